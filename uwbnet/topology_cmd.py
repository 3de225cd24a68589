"""``uwbnet topology``: resolution and ghost maps of a scenario's deployment, and placement.

The I/O shell around :mod:`fusion_center.topology`: turns a scenario (``sim_nodes.scene``)
into a network geometry, a band, an area and candidate sensor sites; draws the maps.
"""

from __future__ import annotations

import itertools
import math
import os
import time
from pathlib import Path
from typing import Any, Literal

import numpy as np

from fusion_center.topology import (
    Area,
    AreaEvaluation,
    Band,
    GreedyPlacementOptimizer,
    NetworkGeometry,
    SiteCandidates,
    ambiguity,
    compose_network,
    evaluate_area,
    even_selection,
    placement_cost,
)
from sim_nodes.scene import BAT_ANTENNAS, Scenario

#: Robot headings whose receiver positions stand in for the full turn (0 and 90 degrees
#: give the four distinct receiver positions of a turn in quarter steps).
ROBOT_HEADINGS = (0.0, math.pi / 2)


def scenario_band(scenario: Scenario) -> Band:
    """The band analysed: the channel's ``band`` if set, else the radar's pass band above its
    high-pass edge, Hz."""
    if scenario.channel.band is not None:
        return Band(f_low=scenario.channel.band[0], f_high=scenario.channel.band[1])
    r = scenario.radar
    return Band(f_low=max(r.f_low, r.highpass), f_high=r.f_high)


def scenario_area(scenario: Scenario, nx: int = 200, ny: int = 200) -> Area:
    """The area of interest: the room's outline, else the walking area of the people (their
    waypoints plus 1 m) clipped to the walls, else the walls' extent."""
    if scenario.room is not None:
        box = np.array(scenario.room.outline, float)
        lo, hi = box.min(axis=0), box.max(axis=0)
    else:
        walls = np.array([p for w in scenario.walls for p in (w.start, w.end)], float)
        nodes = np.array([n.pose[:2] for n in scenario.nodes], float).reshape(-1, 2)
        extent = walls if len(walls) else nodes
        lo, hi = extent.min(axis=0), extent.max(axis=0)
        if scenario.people:
            way = np.array([p for person in scenario.people for p in person.waypoints], float)
            lo = np.maximum(lo, way.min(axis=0) - 1.0)
            hi = np.minimum(hi, way.max(axis=0) + 1.0)
    return Area(x_min=lo[0], y_min=lo[1], x_max=hi[0], y_max=hi[1], nx=nx, ny=ny)


def _node_antennas(x: float, y: float, yaw: float) -> tuple[np.ndarray, np.ndarray]:
    """World x, y of a bat node's tx (1, 2) and rx1, rx2 (2, 2) (default antenna layout)."""
    c, s = math.cos(yaw), math.sin(yaw)
    pos = {
        name: (x + c * p[0] - s * p[1], y + s * p[0] + c * p[1])
        for name, (p, _, _) in BAT_ANTENNAS.items()
    }
    return np.array([pos["tx"]]), np.array([pos["rx1"], pos["rx2"]])


def scenario_geometry(scenario: Scenario, links: Literal["all", "own"] = "all") -> NetworkGeometry:
    """The scenario's network as transmit positions, receivers and links.

    Static bat nodes give their transmitter and two receivers (with antenna overrides);
    ``links="all"``: every receiver hears every node's transmitter (the MIMO network of Fig.
    17), ``"own"``: a node hears only itself. A robot gives its stops as the transmitter's
    track (the virtual array) and its receivers at the headings :data:`ROBOT_HEADINGS` of each
    stop, each hearing only its own stop's transmission.
    """
    _, pos = scenario.antenna_positions()
    tx_rows, rx_rows, pairs = [], [], []
    for i, _node in enumerate(scenario.nodes):
        base = 3 * i  # antenna_positions lists tx, rx1, rx2 per node
        tx_rows.append(pos[base, :2])
        rx_rows += [pos[base + 1, :2], pos[base + 2, :2]]
        pairs += [(i, 2 * i), (i, 2 * i + 1)]
    if scenario.robot is not None:
        rb = scenario.robot
        side = np.array([0.5, -0.5]) * rb.baseline
        for stop in rb.stops:
            t = len(tx_rows)
            tx_rows.append(np.array(stop, float))
            for h in ROBOT_HEADINGS:
                for sd in side:
                    pairs.append((t, len(rx_rows)))
                    rx_rows.append(
                        np.array([stop[0] - math.sin(h) * sd, stop[1] + math.cos(h) * sd])
                    )
    tx, rx = np.array(tx_rows), np.array(rx_rows)
    if scenario.robot is None and links == "all":
        return NetworkGeometry(transmitters=tx, receivers=rx)
    return NetworkGeometry(transmitters=tx, receivers=rx, links=np.array(pairs))


def _inside_objects(scenario: Scenario, pts: np.ndarray, margin: float) -> np.ndarray:
    """Whether points (N, 2) lie within ``margin`` of an object's footprint."""
    from matplotlib.path import Path as PolyPath

    hit = np.zeros(len(pts), bool)
    for o in scenario.objects:
        poly = PolyPath(np.array(o.footprint, float))
        hit |= poly.contains_points(pts, radius=margin) | poly.contains_points(pts, radius=-margin)
    return hit


def wall_sites(
    scenario: Scenario,
    area: Area,
    kind: Literal["bat", "receiver"],
    spacing: float = 1.0,
    inset: float = 0.3,
) -> SiteCandidates:
    """Candidate sites along the area's edges, ``inset`` inside, every ``spacing`` metres,
    in order around the perimeter (counter-clockwise from the lower-left corner).

    A ``bat`` site is a bat node looking into the area (tx on the site, receivers 0.5 m to
    either side along the wall); a ``receiver`` site one stationary receiver. Sites with an
    antenna on an object's footprint (0.2 m margin) are dropped.
    """
    x0, y0 = area.x_min + inset, area.y_min + inset
    x1, y1 = area.x_max - inset, area.y_max - inset
    corners = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]])
    sites, yaws = [], []
    for a, b in itertools.pairwise(corners):
        length = float(np.linalg.norm(b - a))
        n = max(1, round(length / spacing))
        d = (b - a) / length
        inward = math.atan2(d[0], -d[1])  # left normal of a counter-clockwise edge
        for s in (np.arange(n) + 0.5) * length / n:
            sites.append(a + s * d)
            yaws.append(inward)
    pos = np.array(sites)
    tx, rx = [], []
    for (x, y), yaw in zip(pos, yaws, strict=True):
        if kind == "bat":
            t, r = _node_antennas(x, y, yaw)
        else:
            t, r = np.zeros((0, 2)), np.array([[x, y]])
        tx.append(t)
        rx.append(r)
    tx_a, rx_a = np.array(tx).reshape(len(pos), -1, 2), np.array(rx).reshape(len(pos), -1, 2)
    allpts = np.concatenate([pos[:, None], tx_a, rx_a], axis=1)
    bad = _inside_objects(scenario, allpts.reshape(-1, 2), 0.2).reshape(len(pos), -1).any(axis=1)
    keep = ~bad
    return SiteCandidates(positions=pos[keep], transmitters=tx_a[keep], receivers=rx_a[keep])


# --- plots -----------------------------------------------------------------------------------


def _save(fig: Any, png: Path) -> None:
    part = png.with_name(png.stem + ".partial" + png.suffix)
    fig.savefig(part, dpi=110, format="png")
    os.replace(part, png)


def _draw_network(ax: Any, net: NetworkGeometry, scenario: Scenario | None) -> None:
    if scenario is not None:
        for w in scenario.walls:
            ax.plot(*np.array([w.start, w.end]).T, color="0.3", lw=2)
        if scenario.room is not None:
            ax.plot(*np.array(scenario.room.outline).T, color="0.3", lw=2)
        for o in scenario.objects:
            ax.fill(*np.array(o.footprint).T, color="0.5", alpha=0.6)
    ax.plot(*net.transmitters.T, "r^", ms=4, label="Tx positions")
    ax.plot(*net.receivers.T, "wv", mec="k", ms=5, label="Rx")


def plot_evaluation(
    png: Path,
    evaluation: AreaEvaluation,
    net: NetworkGeometry,
    band: Band,
    area: Area,
    scenario: Scenario | None = None,
    title: str = "",
) -> None:
    """Three panels: mean 3 dB main-lobe width, worst ghost per reference point, and the AF
    (dB) of the reference point with the worst ghost, with the antennas."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ext = (area.x_min, area.x_max, area.y_min, area.y_max)
    dx = (evaluation.x[1] - evaluation.x[0]) if len(evaluation.x) > 1 else area.x_max - area.x_min
    dy = (evaluation.y[1] - evaluation.y[0]) if len(evaluation.y) > 1 else area.y_max - area.y_min
    cell = (
        evaluation.x[0] - dx / 2,
        evaluation.x[-1] + dx / 2,
        evaluation.y[0] - dy / 2,
        evaluation.y[-1] + dy / 2,
    )
    fig, axes = plt.subplots(1, 3, figsize=(17, 5))
    im = axes[0].imshow(evaluation.resolution * 100, origin="lower", extent=cell, cmap="viridis")
    fig.colorbar(im, ax=axes[0], label="mean 3 dB main-lobe width (cm)")
    axes[0].set_title("resolution")
    im = axes[1].imshow(evaluation.ghost_db, origin="lower", extent=cell, cmap="magma", vmax=0)
    fig.colorbar(im, ax=axes[1], label="worst ghost (dB re peak)")
    axes[1].set_title("peak-to-ghost level")
    worst = evaluation.points[int(np.argmax(evaluation.ghost_db))]
    mag = np.abs(ambiguity(net, band, worst.reference, area.points())).reshape(area.ny, area.nx)
    im = axes[2].imshow(
        20 * np.log10(np.maximum(mag, 1e-4)), origin="lower", extent=ext, vmin=-30, vmax=0
    )
    fig.colorbar(im, ax=axes[2], label="|AF| (dB)")
    axes[2].plot(*worst.reference, "c+", ms=12, mew=2, label="reference")
    axes[2].plot(*worst.ghost_position, "co", mfc="none", ms=12, label="worst ghost")
    axes[2].set_title("AF of the point with the worst ghost")
    for ax in axes:
        _draw_network(ax, net, scenario)
        ax.set(xlim=ext[:2], ylim=ext[2:], xlabel="x (m)", ylabel="y (m)", aspect="equal")
    axes[2].legend(loc="upper right", fontsize=7)
    fig.suptitle(title)
    fig.tight_layout()
    _save(fig, png)
    plt.close(fig)


# --- commands --------------------------------------------------------------------------------


def evaluate_scenario(
    scenario: Scenario,
    *,
    grid: int = 200,
    references: tuple[int, int] = (8, 6),
    links: Literal["all", "own"] = "all",
    png: Path | None = None,
) -> dict[str, Any]:
    """Maps of a scenario's deployment; the JSON result of ``uwbnet topology SCENARIO``."""
    band = scenario_band(scenario)
    area = scenario_area(scenario, grid, grid)
    net = scenario_geometry(scenario, links)
    t0 = time.perf_counter()
    ev = evaluate_area(net, band, area, references)
    wall = time.perf_counter() - t0
    out: dict[str, Any] = {
        "scenario": scenario.name,
        **ev.summary(),
        "band_hz": [band.f_low, band.f_high],
        "area_m": [float(v) for v in (area.x_min, area.y_min, area.x_max, area.y_max)],
        "grid": [area.nx, area.ny],
        "references": list(references),
        "transmit_positions": len(net.transmitters),
        "receivers": len(net.receivers),
        "links": net.n_links,
        "wall_s": round(wall, 2),
    }
    if png is not None:
        plot_evaluation(png, ev, net, band, area, scenario, f"{scenario.name}: deployment")
        out["png"] = str(png)
    return out


def optimize_scenario(
    scenario: Scenario,
    k: int,
    *,
    spacing: float = 1.0,
    add: bool = False,
    search_grid: int = 30,
    search_references: tuple[int, int] | None = None,
    rerank: int = 4,
    grid: int = 200,
    references: tuple[int, int] = (8, 6),
    png: Path | None = None,
) -> dict[str, Any]:
    """Choose ``k`` sensor sites for a scenario and compare with a naive placement.

    Static-node scenarios: ``k`` bat nodes on the walls (``add``: in addition to the
    scenario's nodes). Robot scenarios: ``k`` stationary receivers that hear the robot's
    transmitter along its track (Fig. 17), in addition to the robot's own receivers.
    The naive placement spaces the ``k`` sites evenly around the perimeter. The search
    evaluates hundreds of networks, each at the final reference points (``search_references``
    defaults to ``references``) on a coarse ``search_grid`` ghost grid plus the fine window
    around each point; the ``rerank`` best under that proxy and the naive placement are then
    re-evaluated at the final settings (``grid``, ``references``) and the best final
    objective is reported, so "optimized" is never worse than naive on the final maps
    (``improved`` is false when naive wins).
    """
    band = scenario_band(scenario)
    area = scenario_area(scenario, grid, grid)
    robot = scenario.robot is not None
    kind: Literal["bat", "receiver"] = "receiver" if robot else "bat"
    cands = wall_sites(scenario, area, kind, spacing)
    if not 1 <= k <= len(cands):
        raise ValueError(f"--sensors must be 1..{len(cands)} (candidate sites), got {k}")
    fixed = scenario_geometry(scenario) if (robot or add) else None
    search_grid = min(search_grid, grid)
    search_area = area.with_grid(search_grid, max(2, round(search_grid * _aspect(area))))
    search_refs = search_references or references
    fine_area = area.with_grid(grid, max(2, round(grid * _aspect(area))))
    opt = GreedyPlacementOptimizer(
        band,
        search_area,
        search_refs,
        final_area=fine_area,
        final_references=references,
        rerank=rerank,
    )
    t0 = time.perf_counter()
    naive_sel = even_selection(len(cands), k)
    result = opt.optimize(cands, k, fixed, starts=[naive_sel])
    search_s = time.perf_counter() - t0
    naive_search_cost, _ = opt.evaluate(cands, naive_sel, fixed)
    layouts: dict[str, tuple[NetworkGeometry, tuple[int, ...] | None]] = {
        "naive": (compose_network(cands, naive_sel, fixed), None),
        "optimized": (compose_network(cands, result.selection, fixed), result.selection),
    }
    if not robot and not add and k == len(scenario.nodes):
        layouts["deployed"] = (scenario_geometry(scenario), None)
    if add or robot:
        layouts["before"] = (scenario_geometry(scenario), None)
    out: dict[str, Any] = {"scenario": scenario.name, "sensors": k, "kind": kind}
    # The naive and optimized layouts were evaluated at the final settings in the re-ranking.
    evs = {"optimized": result.final_evaluation, "naive": result.start_final_evaluations[0]}
    for name, (net, _) in layouts.items():
        if name not in evs:
            evs[name] = evaluate_area(net, band, fine_area, references)
        out[name] = {**evs[name].summary(), "cost": round(placement_cost(evs[name]), 2)}
    out["sites"] = [[round(float(v), 2) for v in cands.positions[i]] for i in result.selection]
    out["naive_sites"] = [
        [round(float(v), 2) for v in cands.positions[i]] for i in even_selection(len(cands), k)
    ]
    out["improvement"] = {
        "ghost_db": round(out["naive"]["ghost_db"] - out["optimized"]["ghost_db"], 2),
        "resolution_ratio": round(
            out["optimized"]["resolution_m"] / out["naive"]["resolution_m"], 3
        ),
    }
    out["improved"] = result.improved
    out["verdict"] = (
        "optimized beats naive on the final maps by "
        f"{result.start_final_costs[0] - result.final_cost:.2f} dB"
        " of the objective"
        if result.improved
        else "no placement better than naive found on the final maps: keeping naive"
    )
    out.update(
        candidates=len(cands),
        evaluations=result.evaluations,
        reranked=[
            {"selection": list(sel), "search_cost": round(js, 2), "final_cost": round(jf, 2)}
            for sel, js, jf in result.ranking
        ],
        search_s=round(search_s, 1),
        search_cost=round(result.cost, 2),
        naive_search_cost=round(naive_search_cost, 2),
        search_references=list(search_refs),
        search_grid=[search_area.nx, search_area.ny],
    )
    if png is not None:
        for name in ("naive", "optimized"):
            target = png if name == "optimized" else png.with_name(png.stem + "_naive" + png.suffix)
            plot_evaluation(
                target,
                evs[name],
                layouts[name][0],
                band,
                fine_area,
                scenario,
                f"{scenario.name}: {name} placement of {k} {kind} sites",
            )
        out["png"] = str(png)
    return out


def _aspect(area: Area) -> float:
    return (area.y_max - area.y_min) / (area.x_max - area.x_min)


def print_human(result: dict[str, Any]) -> None:
    """The result as ``key: value`` lines (the JSON line follows)."""
    for key, value in result.items():
        print(f"{key:>22}: {value}")  # noqa: T201 (the command's output)
