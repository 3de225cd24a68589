"""Choosing sensor positions from the ambiguity function: greedy placement + local refinement.

Pure numpy. Given candidate sensor sites (each adds transmitters and/or receivers: a bat-type
node adds one transmitter and two receivers, a stationary receiver one receiver, a candidate
track its acquisition positions), a budget of ``k`` sites and optionally a fixed part of the
network (a robot's track and its own receivers), choose the sites minimising

.. math:: J = \\max_p G(p) + 20 \\log_{10} \\bar w

over the reference points ``p`` of the area (worst ghost ``G`` in dB and mean 3 dB main-lobe
width ``w``; :func:`~fusion_center.topology.evaluate.placement_cost`). Section 5 of the CoLOR
chapter derives placement and track rules from the AF; the search here is the usual greedy
forward selection (add the site that lowers ``J`` most) followed by a 1-swap local search
(replace one chosen site by a nearby unused one while ``J`` drops), as for sensor selection
in general.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from .ambiguity import Band, NetworkGeometry
from .evaluate import AreaEvaluation, evaluate_area, placement_cost
from .quality import Area

__all__ = [
    "GreedyPlacementOptimizer",
    "PlacementResult",
    "SiteCandidates",
    "compose_network",
    "even_selection",
]

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class SiteCandidates:
    """Candidate sensor sites.

    Parameters
    ----------
    positions : ndarray, float64, shape (C, 2)
        A representative position of every site (neighbourhoods of the local search), m.
    transmitters : ndarray, float64, shape (C, Tc, 2)
        Transmit positions each site adds (``Tc`` may be 0), m.
    receivers : ndarray, float64, shape (C, Rc, 2)
        Receiver positions each site adds (``Rc`` may be 0), m.
    """

    positions: FloatArray
    transmitters: FloatArray
    receivers: FloatArray

    def __post_init__(self) -> None:
        pos = np.asarray(self.positions, dtype=np.float64).reshape(-1, 2)
        n = len(pos)
        tx = np.asarray(self.transmitters, dtype=np.float64).reshape(n, -1, 2)
        rx = np.asarray(self.receivers, dtype=np.float64).reshape(n, -1, 2)
        if n == 0:
            raise ValueError("need at least one candidate site")
        object.__setattr__(self, "positions", pos)
        object.__setattr__(self, "transmitters", tx)
        object.__setattr__(self, "receivers", rx)

    def __len__(self) -> int:
        return len(self.positions)


def compose_network(
    candidates: SiteCandidates,
    selection: Sequence[int],
    fixed: NetworkGeometry | None = None,
) -> NetworkGeometry:
    """The network of the fixed part plus the selected sites.

    Every antenna of a selected site is linked to every antenna of the other kind (the MIMO
    network of Fig. 17). A fully linked fixed part stays fully linked; a fixed part with its
    own links (a robot hearing only itself) keeps them, and its antennas are linked to the
    sites' antennas.
    """
    sel = np.asarray(list(selection), dtype=np.int64)
    new_tx = candidates.transmitters[sel].reshape(-1, 2)
    new_rx = candidates.receivers[sel].reshape(-1, 2)
    if fixed is None:
        return NetworkGeometry(transmitters=new_tx, receivers=new_rx)
    tx = np.concatenate([fixed.transmitters, new_tx])
    rx = np.concatenate([fixed.receivers, new_rx])
    if fixed.fully_linked:
        return NetworkGeometry(transmitters=tx, receivers=rx)
    n_t0, n_r0 = len(fixed.transmitters), len(fixed.receivers)
    t_all = np.arange(len(tx))
    t_new, r_new = np.arange(n_t0, len(tx)), np.arange(n_r0, len(rx))
    extra = [
        np.stack(np.meshgrid(t_all, r_new, indexing="ij"), -1).reshape(-1, 2),
        np.stack(np.meshgrid(t_new, np.arange(n_r0), indexing="ij"), -1).reshape(-1, 2),
    ]
    links = np.concatenate([fixed.links, *extra])
    return NetworkGeometry(transmitters=tx, receivers=rx, links=links)


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class PlacementResult:
    """Outcome of a placement search.

    Attributes
    ----------
    selection : tuple of int
        Chosen candidate indices.
    cost : float
        Objective ``J`` of the selection (search settings).
    evaluation : AreaEvaluation
        The selection's evaluation at the search settings.
    history : list of (str, tuple, float)
        ``(step, selection, cost)`` after every greedy addition and accepted swap.
    evaluations : int
        Number of networks evaluated.
    """

    selection: tuple[int, ...]
    cost: float
    evaluation: AreaEvaluation
    history: list[tuple[str, tuple[int, ...], float]] = field(default_factory=list)
    evaluations: int = 0


class GreedyPlacementOptimizer:
    """Greedy forward selection of sensor sites, then 1-swap local refinement.

    Parameters
    ----------
    band : Band
    area : Area
        Evaluation area and ghost-search grid (use a coarse grid here: the search evaluates
        hundreds of networks; re-evaluate the result on a fine grid).
    references : (mx, my)
        Reference points of the objective.
    neighbours : int
        Unused sites nearest to a chosen site tried as its replacement in a swap.
    sweeps : int
        Maximum passes of the local refinement over the chosen sites.
    resolution_scale : float
        ``w_0`` of the objective, m.
    """

    def __init__(
        self,
        band: Band,
        area: Area,
        references: tuple[int, int] = (4, 3),
        *,
        neighbours: int = 4,
        sweeps: int = 2,
        resolution_scale: float = 1.0,
    ) -> None:
        self.band = band
        self.area = area
        self.references = references
        self.neighbours = neighbours
        self.sweeps = sweeps
        self.resolution_scale = resolution_scale
        self._cache: dict[tuple[int, ...], tuple[float, AreaEvaluation]] = {}

    def evaluate(
        self,
        candidates: SiteCandidates,
        selection: Sequence[int],
        fixed: NetworkGeometry | None = None,
    ) -> tuple[float, AreaEvaluation]:
        """Objective and evaluation of one selection (cached per sorted selection)."""
        key = tuple(sorted(int(s) for s in selection))
        if key not in self._cache:
            net = compose_network(candidates, key, fixed)
            ev = evaluate_area(net, self.band, self.area, self.references)
            self._cache[key] = (placement_cost(ev, self.resolution_scale), ev)
        return self._cache[key]

    def optimize(
        self,
        candidates: SiteCandidates,
        k: int,
        fixed: NetworkGeometry | None = None,
        starts: Sequence[Sequence[int]] = (),
    ) -> PlacementResult:
        """Choose ``k`` sites: greedy selection, then local refinement of the greedy result and
        of every selection in ``starts`` (e.g. the naive placement); the best one wins, so the
        result is never worse than a given start under the search objective.

        Raises
        ------
        ValueError
            ``k`` outside 1..len(candidates), or a first site that cannot form a network
            with the fixed part (no transmitter or no receiver).
        """
        if not 1 <= k <= len(candidates):
            raise ValueError(f"need 1 <= k <= {len(candidates)} candidate sites, got k = {k}")
        self._cache.clear()
        chosen: list[int] = []
        history: list[tuple[str, tuple[int, ...], float]] = []
        cost = np.inf
        for step in range(k):
            best: tuple[float, int] | None = None
            for c in range(len(candidates)):
                if c in chosen:
                    continue
                try:
                    j, _ = self.evaluate(candidates, [*chosen, c], fixed)
                except ValueError:
                    continue  # e.g. a receiver-only site with no transmitter yet
                if best is None or j < best[0]:
                    best = (j, c)
            if best is None:
                raise ValueError("no candidate site forms a network with the fixed part")
            cost = best[0]
            chosen.append(best[1])
            history.append((f"add {step + 1}", tuple(chosen), cost))
        best_sel, best_cost = self._refine(candidates, chosen, cost, fixed, history, "greedy")
        for n, start in enumerate(starts):
            sel = [int(c) for c in start]
            if len(set(sel)) != k:
                raise ValueError(f"start {n}: need {k} distinct sites")
            j, _ = self.evaluate(candidates, sel, fixed)
            history.append((f"start {n + 1}", tuple(sel), j))
            sel, j = self._refine(candidates, sel, j, fixed, history, f"start {n + 1}")
            if j < best_cost:
                best_sel, best_cost = sel, j
        chosen = best_sel
        cost, evaluation = self.evaluate(candidates, chosen, fixed)
        return PlacementResult(
            selection=tuple(chosen),
            cost=cost,
            evaluation=evaluation,
            history=history,
            evaluations=len(self._cache),
        )

    def _refine(
        self,
        candidates: SiteCandidates,
        chosen: list[int],
        cost: float,
        fixed: NetworkGeometry | None,
        history: list[tuple[str, tuple[int, ...], float]],
        label: str,
    ) -> tuple[list[int], float]:
        """1-swap local search: replace a chosen site by one of its nearest unused sites
        while the objective drops, at most ``sweeps`` passes."""
        pos = candidates.positions
        for sweep in range(self.sweeps):
            improved = False
            for i in range(len(chosen)):
                free = np.array([c for c in range(len(candidates)) if c not in chosen])
                if free.size == 0:
                    break
                near = free[np.argsort(np.linalg.norm(pos[free] - pos[chosen[i]], axis=1))]
                for c in near[: self.neighbours]:
                    trial = [*chosen[:i], int(c), *chosen[i + 1 :]]
                    j, _ = self.evaluate(candidates, trial, fixed)
                    if j < cost - 1e-9:
                        chosen, cost, improved = trial, j, True
                        history.append((f"{label} swap {sweep + 1}", tuple(chosen), cost))
            if not improved:
                break
        return chosen, cost


def even_selection(n_candidates: int, k: int) -> tuple[int, ...]:
    """The naive placement: ``k`` sites evenly spaced along the candidate order (for sites
    ordered along the walls, evenly spaced around the perimeter)."""
    if not 1 <= k <= n_candidates:
        raise ValueError(f"need 1 <= k <= {n_candidates}, got {k}")
    return tuple(int(i) for i in np.floor(np.arange(k) * n_candidates / k))
