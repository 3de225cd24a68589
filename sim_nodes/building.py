"""Generated buildings for scale tests: a row of rooms sized to a number of sensors.

:func:`building_scenario` builds a validated :class:`~sim_nodes.scene.Scenario` (the same model
as the shipped TOML files) programmatically: ``ceil(N / 4)`` rooms of ``ROOM_LENGTH`` x
``ROOM_DEPTH`` m side by side along x, separated by brick partitions with a door in the middle,
concrete outer walls, and four bat-type sensors per room on the long walls (two on the south
wall looking north, two on the north wall looking south, each turned a little towards the room
centre, as in foyer3). People walk back and forth along the building through the doors, each
over a stretch of up to three rooms, starting a few metres before its centre, so that they
cross room (and fusion cell) borders soon after the start and then every few seconds.

Pure: no files, no clocks.
"""

from __future__ import annotations

import math

import numpy as np

from sim_nodes.scene import Scenario, parse_scenario

#: Room size along x and y, m.
ROOM_LENGTH = 10.0
ROOM_DEPTH = 8.0
#: Sensors per room.
NODES_PER_ROOM = 4
#: A person starts this far (m) before the centre of their route.
START_OFFSET = 9.0
#: Half width of the doors in the partitions, m.
DOOR_HALF_WIDTH = 1.0


def building_length(n_nodes: int) -> float:
    """Length (x extent, m) of the building generated for ``n_nodes`` sensors."""
    return ROOM_LENGTH * math.ceil(n_nodes / NODES_PER_ROOM)


def building_scenario(
    n_nodes: int, n_people: int, seed: int = 1, *, name: str | None = None
) -> Scenario:
    """A row of rooms with ``n_nodes`` bat-type sensors and ``n_people`` walking people.

    Parameters
    ----------
    n_nodes : int
        Number of sensors, >= 1. Rooms: ``ceil(n_nodes / 4)``; the last room may have fewer.
    n_people : int
        Number of people, >= 0.
    seed : int
        Seed of the people's routes (start room, direction) and walking speeds.
    name : str, optional
        Scenario name (default ``building{n_nodes}x{n_people}``).

    Returns
    -------
    Scenario
        Node ids ``n000``, ``n001``, ... in room order; the image2d channel with first-order
        wall reflections (the static channel is computed once per node, so its cost is only
        paid at start-up).
    """
    if n_nodes < 1:
        raise ValueError(f"a building needs at least one sensor, not {n_nodes}")
    if n_people < 0:
        raise ValueError(f"number of people must be >= 0, not {n_people}")
    rooms = math.ceil(n_nodes / NODES_PER_ROOM)
    length = rooms * ROOM_LENGTH
    walls = [
        {"start": [0.0, 0.0], "end": [length, 0.0], "material": "concrete"},
        {"start": [0.0, ROOM_DEPTH], "end": [length, ROOM_DEPTH], "material": "concrete"},
        {"start": [0.0, 0.0], "end": [0.0, ROOM_DEPTH], "material": "concrete"},
        {"start": [length, 0.0], "end": [length, ROOM_DEPTH], "material": "concrete"},
    ]
    mid = ROOM_DEPTH / 2
    for r in range(1, rooms):
        x = r * ROOM_LENGTH
        for y0, y1 in ((0.0, mid - DOOR_HALF_WIDTH), (mid + DOOR_HALF_WIDTH, ROOM_DEPTH)):
            walls.append({"start": [x, y0], "end": [x, y1], "material": "brick", "thickness": 0.12})
    for w in walls:
        w.setdefault("thickness", 0.05)
    nodes = []
    # Sensor k of a room: south wall at 1/4 and 3/4 of the room, then the north wall.
    offsets = [
        (0.25, 0.25, math.pi / 2 + 0.3),
        (0.75, 0.25, math.pi / 2 - 0.3),
        (0.25, ROOM_DEPTH - 0.25, -math.pi / 2 - 0.3),
        (0.75, ROOM_DEPTH - 0.25, -math.pi / 2 + 0.3),
    ]
    for i in range(n_nodes):
        room, k = divmod(i, NODES_PER_ROOM)
        fx, y, yaw = offsets[k]
        x = (room + fx) * ROOM_LENGTH
        nodes.append({"id": f"n{i:03d}", "role": "bat", "pose": [x, y, 1.2, yaw]})
    rng = np.random.default_rng(seed)
    people: list[dict] = []
    span = min(3, rooms)  # rooms a person's route covers
    for j in range(n_people):
        first = int(rng.integers(0, rooms - span + 1))
        lane = mid + (1.5 if j % 2 else -1.5) * (0.5 + 0.5 * ((j // 2) % 2))
        centre = (first + span / 2) * ROOM_LENGTH
        west, east = first * ROOM_LENGTH + 2.0, (first + span) * ROOM_LENGTH - 2.0
        # Start START_OFFSET m before the route's centre, walk to the far end and back: a
        # person crosses the centre (and the borders near it) within seconds of the start.
        if rng.random() < 0.5:
            x_start, x_end = max(west, centre - START_OFFSET), east
        else:
            x_start, x_end = min(east, centre + START_OFFSET), west
        pts = [[x_start, lane]]
        # Through the doors where the route crosses a partition, on the lane's side of the
        # door (people on the two sides pass each other 0.8 m apart).
        step = 1 if x_end > x_start else -1
        y_door = mid + 0.4 * np.sign(lane - mid)
        for r in range(1, rooms)[::step]:
            xd = r * ROOM_LENGTH
            if min(x_start, x_end) + 1.5 < xd < max(x_start, x_end) - 1.5:
                pts += [[xd - 1.5 * step, y_door], [xd + 1.5 * step, y_door]]
        pts.append([x_end, lane])
        people.append(
            {
                "id": j + 1,
                "waypoints": pts,
                "speed": float(round(rng.uniform(1.1, 1.4), 2)),
                # Staggered entries: people on the same route do not walk in step.
                "enter": float(round(rng.uniform(0.0, 3.0), 2)) if j else 0.0,
            }
        )
    data = {
        "name": name or f"building{n_nodes}x{n_people}",
        "description": f"generated: {rooms} rooms in a row, {n_nodes} sensors, {n_people} people",
        "frame_period": 0.02,
        "radar": {"rate": 50.0},
        "channel": {"model": "image2d", "reflection_order": 1},
        "materials": {
            "concrete": {"reflection": -0.55, "transmission_loss_db": 20.0, "permittivity": 5.3},
            "brick": {"reflection": -0.4, "transmission_loss_db": 7.0, "permittivity": 4.0},
        },
        "walls": walls,
        "nodes": nodes,
        "people": people,
    }
    return parse_scenario(data, source=data["name"])
