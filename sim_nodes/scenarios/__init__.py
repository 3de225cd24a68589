"""Shipped scenario files (``*.toml``); load them with :func:`sim_nodes.scene.load_scenario`."""
