"""TOML configuration of the deployment processes: validation, units, precedence."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from uwbnet.config import (
    ConfigError,
    FusionFile,
    NodeFile,
    SimNodeFile,
    ZenohModel,
    load_config,
    zenoh_config,
)

EXAMPLES = Path(__file__).parents[3] / "deploy" / "examples"


@pytest.mark.parametrize(
    ("model", "name"), [(NodeFile, "node"), (FusionFile, "fusion"), (SimNodeFile, "simnode")]
)
def test_shipped_examples_validate(model, name):
    cfg = load_config(model, EXAMPLES / f"{name}.toml", env={})
    assert cfg.zenoh.tls is not None and cfg.zenoh.lease == 0.75


def _load(tmp_path, text, model=NodeFile, **kw):  # type: ignore[no-untyped-def]
    p = tmp_path / "c.toml"
    p.write_text(text)
    return load_config(model, p, env=kw.pop("env", {}), **kw)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('node = "a"\nstatu_period = 1\n', "statu_period: unknown key"),
        ('node = "a"\nstatus_period = "3 cm"\n', "status_period: unit 'cm' is not a time unit"),
        ('node = "a"\nstatus_period = "soon"\n', "status_period: not a duration"),
        ('node = "a"\nstatus_period = -1\n', "status_period: Input should be greater than 0"),
        ("node = 3\n", "node: Input should be a valid string"),
        ('node = "a b"\n', "node: String should match pattern"),
        ('node = "a"\n[zenoh]\nmode = "hub"\n', "zenoh.mode: Input should be"),
        ('node = "a"\n[zenoh]\nlease = true\n', "zenoh.lease"),
        ('node = "a"\n[describe]\npose = [1, 2]\n', "describe.pose"),
        ("publish_ir = true\n", "node: required key missing"),
        ("node = \n", "not valid TOML"),
    ],
)
def test_bad_configs_give_one_line_naming_the_field(tmp_path, text, message):
    with pytest.raises(ConfigError) as info:
        _load(tmp_path, text)
    assert message in str(info.value)
    assert "\n" not in str(info.value)


def test_durations_take_units(tmp_path):
    cfg = _load(tmp_path, 'node = "a"\nstatus_period = "250 ms"\n[zenoh]\nlease = 2\n')
    assert cfg.status_period == pytest.approx(0.25)
    assert cfg.zenoh.lease == 2.0


def test_precedence_cli_over_environment_over_file(tmp_path):
    text = 'node = "a"\nnet = "file"\n[zenoh]\nconnect = ["tcp/1.2.3.4:7447"]\n'
    assert _load(tmp_path, text).net == "file"
    env = {"UWBNET_NET": "env", "UWBNET_CONNECT": "tcp/5.6.7.8:1, tcp/9.9.9.9:2"}
    cfg = _load(tmp_path, text, env=env)
    assert cfg.net == "env"
    assert cfg.zenoh.connect == ["tcp/5.6.7.8:1", "tcp/9.9.9.9:2"]
    cfg = _load(tmp_path, text, env=env, overrides={("net",): "cli", ("zenoh", "mode"): None})
    assert cfg.net == "cli" and cfg.zenoh.mode == "peer"


def test_tls_refuses_plain_endpoints_and_missing_files(tmp_path):
    tls = {"ca": str(tmp_path / "ca.pem"), "cert": "x.pem", "key": "x.key"}
    with pytest.raises(ConfigError, match="not tls/"):
        zenoh_config(ZenohModel(connect=["tcp/1.2.3.4:7447"], tls=tls), "n")
    with pytest.raises(ConfigError, match=r"^zenoh\.tls\.ca: cannot read .*ca\.pem: No such file"):
        zenoh_config(ZenohModel(mode="client", connect=["tls/1.2.3.4:7447"], tls=tls), "n")
    with pytest.raises(ConfigError, match=r"needs zenoh\.tls"):
        zenoh_config(ZenohModel(access={"members": ["a"]}), "n")


def test_cli_reports_a_bad_config_in_one_line(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text('node = "a"\n[driver]\nnme = "serial"\n')
    exe = str(Path(sys.executable).with_name("uwbnet"))
    for cmd in ("node", "fusion", "simnode"):
        r = subprocess.run([exe, cmd, "--config", str(p)], capture_output=True, text=True)
        assert r.returncode == 1
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("uwbnet: error: "), r.stderr
    r = subprocess.run(
        [exe, "node", "--config", str(tmp_path / "missing.toml")], capture_output=True, text=True
    )
    assert r.returncode == 1 and "cannot read" in r.stderr


@pytest.mark.parametrize("name", ["peer-one-host", "client-to-router", "router"])
def test_shipped_zenoh_configs_are_valid_zenoh_configs(name):
    import json

    import zenoh

    conf = zenoh.Config.from_file(str(EXAMPLES.parent / "zenoh" / f"{name}.json5"))
    assert json.loads(conf.get_json("mode")) == name.split("-")[0]


def test_shipped_router_acl_matches_the_generated_one():
    import json

    import zenoh

    from uwbnet.config import AccessModel, access_control

    conf = zenoh.Config.from_file(str(EXAMPLES.parent / "zenoh" / "router.json5"))
    shipped = json.loads(conf.get_json("access_control"))
    generated = access_control(
        AccessModel(members=["fusion", "hostA", "hostB", "recorder"], viewers=["viewer"]), "NET"
    )
    assert [r["key_exprs"] for r in shipped["rules"]] == [
        r["key_exprs"] for r in generated["rules"]
    ]
    assert [s["cert_common_names"] for s in shipped["subjects"]] == [
        s["cert_common_names"] for s in generated["subjects"]
    ]


def test_tls_files_must_be_pem_and_a_tls_router_must_listen_on_tls(tmp_path):
    junk = tmp_path / "junk.pem"
    junk.write_text("not a certificate\n")
    tls = {"ca": str(junk), "cert": str(junk), "key": str(junk)}
    with pytest.raises(ConfigError, match=r"zenoh\.tls\.ca: .* is not a PEM file"):
        zenoh_config(ZenohModel(mode="client", connect=["tls/1.2.3.4:7447"], tls=tls), "n")
    with pytest.raises(ConfigError, match=r"needs a tls/\.\.\. listen endpoint"):
        zenoh_config(ZenohModel(mode="router", tls=tls), "n")


def test_a_router_that_cannot_listen_exits_with_one_line(tmp_path):
    import socket

    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        p = tmp_path / "f.toml"
        p.write_text(f'[zenoh]\nmode = "router"\nlisten = ["tcp/127.0.0.1:{port}"]\n')
        exe = str(Path(sys.executable).with_name("uwbnet"))
        r = subprocess.run(
            [exe, "fusion", "--config", str(p)], capture_output=True, text=True, timeout=60
        )
    assert r.returncode == 1
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("uwbnet: error: fusion: zenoh:"), r.stderr
