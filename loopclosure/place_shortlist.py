"""The shortlist of a place query: the rows it chooses its candidates from.

`PlaceDatabase._shortlist` (`loopclosure.place_database`, step 1) ranks the allowed
rows by the combined normalised prefilter distance p (unitless) and keeps the K
smallest, or with the polar grids the ``grid_shortlist`` smallest with their grid
similarities c; `Shortlist.chosen` picks the candidates among them
(`loopclosure.grid_rerank.union_of_rankings`: the K smallest p and up to
``grid_extra`` more by p - w c), and `Shortlist.merged` joins the shortlists of two
disjoint row sets (`PlaceDatabase.query_stored` screening only newly allowed rows).

A query that ranks the rows by two lists of distances (its own description's p and
the smallest p over its offset viewpoints, `PlaceDatabaseConfig.viewpoint_order`)
orders them by `rank_interleave`: row j's place is its best rank in any list,

    r(j) = min_l rank_l(j)        (rank_l: 0 for list l's smallest distance),

ties by the smaller distance of the lists ranking it so, then by row.  The first
2 n rows of two lists hold both lists' n best, whatever the lists' distances are:
a list whose distances run lower (a minimum over more descriptions) cannot crowd
the other's best rows out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from loopclosure.grid_rerank import union_of_rankings
from loopclosure.place_config import PlaceDatabaseConfig

Array = NDArray[np.float64]


def rank_interleave(per_list: list[NDArray[np.floating]] | NDArray[np.floating]
                    ) -> NDArray[np.intp]:
    """Positions ordered by their best rank over several distance lists (module
    docstring; ``inf``: the list does not hold the row, never ranked by it)."""
    return rank_interleave_with_distance(per_list)[0]


def rank_interleave_with_distance(
    per_list: list[NDArray[np.floating]] | NDArray[np.floating],
) -> tuple[NDArray[np.intp], Array]:
    """`rank_interleave`'s order and each position's distance in the list that ranks it
    best (the smaller on ties; ``inf`` where no list holds it)."""
    d = np.atleast_2d(np.asarray(per_list, dtype=float))
    ranks = np.full(d.shape, np.inf)
    for i, dist in enumerate(d):
        finite = np.flatnonzero(np.isfinite(dist))
        ranks[i, finite[np.argsort(dist[finite], kind="stable")]] = np.arange(len(finite))
    best = ranks.min(axis=0)
    distance = np.where(ranks == best, d, np.inf).min(axis=0)
    return np.lexsort((np.arange(d.shape[1]), distance, best)), distance


def vote_picks(order: NDArray[np.intp], votes: Array, split: int, k: int
               ) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """The two heads of `vote_fused_order`: the first `split` of `order`, and the
    positions with the highest vote (> 0; ties by position) not among them, up to
    `k` in all (``votes`` is over every position, `order` may hold fewer)."""
    order = np.asarray(order, np.intp)
    votes = np.asarray(votes, float)
    head = order[: min(split, k)]
    free = votes > 0
    free[head] = False
    voted = np.flatnonzero(free)
    voted = voted[np.lexsort((voted, -votes[voted]))][: max(k - len(head), 0)]
    return head, voted


def vote_fused_order(order: NDArray[np.intp], votes: Array, split: int, k: int
                     ) -> NDArray[np.intp]:
    """Positions ordered as a query with the pair vote picks its K candidates
    (`PlaceDatabaseConfig.vote`): the first `split` of the prefilter's `order`, then
    the positions with the highest vote (> 0; ties by position) not among them, up to
    `k`, then the rest of `order`.

    Args:
        order: ``(M,)`` the prefilter's order of the positions (a permutation).
        votes: ``(M,)`` vote score of every position (0: no vote).
        split: positions of `order` kept first; k: candidates in all.
    """
    order = np.asarray(order, np.intp)
    first = np.concatenate(vote_picks(order, votes, split, k)).astype(np.intp)
    return np.concatenate([first, order[~np.isin(order, first)]]).astype(np.intp)


def with_votes(pick: NDArray[np.intp], votes: Array, split: int, k: int
               ) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """The candidates of a query with the pair vote, as `vote_fused_order` orders
    them: ``(take, voted)``, `take` the positions in `pick` (the prefilter's
    candidates, its K first, then the grids' extras) kept, `voted` the vote's rows
    joining them.  The candidates are then ``pick[take[:split']], voted,
    pick[take[split':]]`` with split' = ``min(split, k)``: the first `split` of
    `pick`, the vote's best rows not among them nor among the extras (`votes`:
    ``(M,)`` over every stored row, 0 where not allowed), the prefilter's next ones
    up to `k`, and the extras (positions `k` and on) last."""
    votes = np.array(votes, float)
    votes[pick[k:]] = 0.0
    head, voted = vote_picks(pick[:k], votes, split, k)
    split = len(head)
    rest = np.flatnonzero(~np.isin(pick[split:k], voted)) + split
    take = np.concatenate([np.arange(split), rest[: k - split - len(voted)],
                           np.arange(k, len(pick))]).astype(np.intp)
    return take, voted.astype(np.intp)


def rows_mask(rows: NDArray[np.intp], m: int) -> NDArray[np.bool_]:
    """Boolean mask ``(m,)`` over insertion order holding `rows`."""
    mask = np.zeros(m, bool)
    mask[rows] = True
    return mask


@dataclass(slots=True, frozen=True)
class Shortlist:
    """The rows a query chooses its candidates from (`PlaceDatabase._shortlist`), in
    increasing p (ties by row), or in `rank_interleave` order when `ordered`:
    insertion rows, exact p, exact raw prefilter stage distances, grid similarity c
    (None without the grids' candidates), and p of every row when asked
    (`CandidateSet.prefilter_all`)."""

    rows: NDArray[np.intp]
    prefilter: Array
    raw: dict[str, Array]
    similarity: Array | None
    prefilter_all: Array | None
    ordered: bool = False

    def chosen(self, k: int, config: PlaceDatabaseConfig) -> NDArray[np.intp]:
        """Positions of the candidates (`loopclosure.grid_rerank.union_of_rankings`;
        the first K without grid similarities), in increasing p (in the shortlist's
        order when `ordered`)."""
        if self.similarity is None:
            return np.arange(min(k, len(self.rows)))
        return union_of_rankings(self.prefilter, self.similarity, k, config.grid_extra,
                                 config.grid_weight, ordered=self.ordered)

    def merged(self, other: Shortlist, size: int) -> Shortlist:
        """The shortlist of both shortlists' rows (disjoint): the `size` smallest p."""
        rows = np.concatenate([self.rows, other.rows])
        pre = np.concatenate([self.prefilter, other.prefilter])
        keep = np.lexsort((rows, pre))[:size]
        similarity = (None if self.similarity is None or other.similarity is None
                      else np.concatenate([self.similarity, other.similarity])[keep])
        return Shortlist(rows[keep], pre[keep],
                          {s: np.concatenate([d, other.raw[s]])[keep] for s, d in self.raw.items()},
                          similarity, None)


__all__ = ["Shortlist", "rank_interleave", "rows_mask", "vote_fused_order", "vote_picks",
           "with_votes"]
