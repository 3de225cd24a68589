"""Radar drivers behind one interface, found by name in a lazy registry.

Back-ends are imported only when asked for (python-can's ``BACKENDS``): a missing optional
dependency gives a clear error, never a failed import of ``node_agent``. Third-party drivers
register under the entry-point group ``uwbnet.drivers``.
"""

from __future__ import annotations

import importlib
from importlib.metadata import entry_points

from node_agent.drivers.base import Acquisition, DriverError, RadarDriver

#: name -> (module, class). The simulated driver lives in sim_nodes (it uses the simulator).
BACKENDS: dict[str, tuple[str, str]] = {
    "sim": ("sim_nodes.driver", "SimulatedDriver"),
    "serial": ("node_agent.drivers.serial", "SerialDriver"),
}


def get_driver_class(name: str) -> type[RadarDriver]:
    """The driver class registered as ``name`` (built in, or entry point ``uwbnet.drivers``)."""
    if name in BACKENDS:
        module_name, class_name = BACKENDS[name]
        try:
            module = importlib.import_module(module_name)
        except ImportError as exc:
            raise DriverError(f"driver {name!r} needs {exc.name}, which is not installed") from None
        cls: type[RadarDriver] = getattr(module, class_name)
        return cls
    for ep in entry_points(group="uwbnet.drivers"):
        if ep.name == name:
            loaded: type[RadarDriver] = ep.load()
            return loaded
    known = sorted(BACKENDS) + sorted(ep.name for ep in entry_points(group="uwbnet.drivers"))
    raise DriverError(f"unknown driver {name!r} (known: {', '.join(known)})")


__all__ = ["BACKENDS", "Acquisition", "DriverError", "RadarDriver", "get_driver_class"]
