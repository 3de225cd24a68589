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

The search scores hundreds of networks, so it uses a cheaper proxy of the final evaluation (a
coarser ghost-search grid; by default the same reference points). A proxy can be overfitted:
the best selection under the proxy need not be the best on the final maps. So the search ends
with a re-ranking, as in two-stage (proxy then exact) model selection: the ``rerank``
best distinct selections under the proxy, plus every given start (the naive placement), are
evaluated at the final settings and the lowest final ``J`` wins. A start is always among them,
so the result is never worse than it on the final objective; if a start wins, nothing better
was found and :attr:`PlacementResult.improved` says so.
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

#: Final-objective gain (dB) below which a start (the naive placement) is kept.
_MARGIN_DB = 0.01


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
        Number of networks evaluated at the search settings.
    final_cost : float
        Objective ``J`` of the selection at the final settings (the search settings when no
        final settings were given).
    final_evaluation : AreaEvaluation or None
        The selection's evaluation at the final settings.
    ranking : list of (tuple, float, float)
        ``(selection, search cost, final cost)`` of every re-ranked selection, best final
        first.
    start_final_costs : list of float
        Final ``J`` of every given start, in order.
    start_final_evaluations : list of AreaEvaluation
        Their evaluations at the final settings.
    """

    selection: tuple[int, ...]
    cost: float
    evaluation: AreaEvaluation
    history: list[tuple[str, tuple[int, ...], float]] = field(default_factory=list)
    evaluations: int = 0
    final_cost: float = np.nan
    final_evaluation: AreaEvaluation | None = None
    ranking: list[tuple[tuple[int, ...], float, float]] = field(default_factory=list)
    start_final_costs: list[float] = field(default_factory=list)
    start_final_evaluations: list[AreaEvaluation] = field(default_factory=list)

    @property
    def improved(self) -> bool:
        """Whether the selection beats every given start on the final objective (strictly,
        by more than 0.01 dB); ``True`` when there were no starts."""
        return all(self.final_cost < c - _MARGIN_DB for c in self.start_final_costs)


class GreedyPlacementOptimizer:
    """Greedy forward selection of sensor sites, then 1-swap local refinement.

    Parameters
    ----------
    band : Band
    area : Area
        Evaluation area and ghost-search grid of the search proxy (a coarse grid: the search
        evaluates hundreds of networks).
    references : (mx, my)
        Reference points of the search objective (use the final ones or a superset: the worst
        ghost is a maximum over them, and fewer points miss the worst one).
    final_area : Area, optional
        Ghost-search grid of the final evaluation (the maps reported); with it, the search
        ends with the re-ranking at the final settings.
    final_references : (mx, my), optional
        Reference points of the final evaluation (default ``references``).
    rerank : int
        Distinct best selections under the proxy re-evaluated at the final settings (the
        starts come on top).
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
        final_area: Area | None = None,
        final_references: tuple[int, int] | None = None,
        rerank: int = 4,
        neighbours: int = 4,
        sweeps: int = 2,
        resolution_scale: float = 1.0,
    ) -> None:
        if rerank < 1:
            raise ValueError(f"rerank must be >= 1, got {rerank}")
        self.band = band
        self.area = area
        self.references = references
        self.final_area = final_area
        self.final_references = final_references or references
        self.rerank = rerank
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

    def evaluate_final(
        self,
        candidates: SiteCandidates,
        selection: Sequence[int],
        fixed: NetworkGeometry | None = None,
    ) -> tuple[float, AreaEvaluation]:
        """Objective and evaluation of one selection at the final settings (the search
        settings when no ``final_area`` was given)."""
        if self.final_area is None:
            return self.evaluate(candidates, selection, fixed)
        net = compose_network(candidates, sorted(int(s) for s in selection), fixed)
        ev = evaluate_area(net, self.band, self.final_area, self.final_references)
        return placement_cost(ev, self.resolution_scale), ev

    def optimize(
        self,
        candidates: SiteCandidates,
        k: int,
        fixed: NetworkGeometry | None = None,
        starts: Sequence[Sequence[int]] = (),
    ) -> PlacementResult:
        """Choose ``k`` sites: greedy selection, then local refinement of the greedy result and
        of every selection in ``starts`` (e.g. the naive placement) under the search proxy;
        then the ``rerank`` best distinct ``k``-site selections under the proxy and every start
        are evaluated at the final settings and the lowest final objective wins, so the result
        is never worse than a given start on the final objective.

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
        self._refine(candidates, chosen, cost, fixed, history, "greedy")
        start_keys = []
        for n, start in enumerate(starts):
            sel = [int(c) for c in start]
            if len(set(sel)) != k or not all(0 <= c < len(candidates) for c in sel):
                raise ValueError(f"start {n}: need {k} distinct sites of 0..{len(candidates) - 1}")
            j, _ = self.evaluate(candidates, sel, fixed)
            history.append((f"start {n + 1}", tuple(sel), j))
            start_keys.append(tuple(sorted(sel)))
            self._refine(candidates, sel, j, fixed, history, f"start {n + 1}")
        evaluations = len(self._cache)
        # Re-rank: the best k-site selections under the proxy (the cache holds every one
        # scored) and the starts, at the final settings.
        full = sorted((j, key) for key, (j, _) in self._cache.items() if len(key) == k)
        pool = list(dict.fromkeys([key for _, key in full[: self.rerank]] + start_keys))
        finals = {key: self.evaluate_final(candidates, key, fixed) for key in pool}
        ranking = sorted(
            ((key, self._cache[key][0], finals[key][0]) for key in pool),
            key=lambda r: (r[2], r[1]),
        )
        best = ranking[0][0]
        if start_keys:
            # Keep the best start unless something beats it clearly (by > 0.01 dB): a tie
            # is no reason to move sensors away from the reference layout.
            best_start = min(start_keys, key=lambda key: finals[key][0])
            if finals[best][0] >= finals[best_start][0] - _MARGIN_DB:
                best = best_start
        cost, evaluation = self.evaluate(candidates, best, fixed)
        return PlacementResult(
            selection=best,
            cost=cost,
            evaluation=evaluation,
            history=history,
            evaluations=evaluations,
            final_cost=finals[best][0],
            final_evaluation=finals[best][1],
            ranking=ranking,
            start_final_costs=[finals[key][0] for key in start_keys],
            start_final_evaluations=[finals[key][1] for key in start_keys],
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
