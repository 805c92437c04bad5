"""Free-space models side by side at one fit: what a check's conflicts are made of.

Used by ``final_precision.py record --models`` on every check that reached the
consistency test (`loopclosure.geometric_check`).  At the check's pose the query's
submap (voxel ``source_voxel``) and the candidate's (voxel ``search.submap_voxel``)
are compared as `loopclosure.free_space.consistency` compares them, and every point
that is no hit (farther than the tolerance from the other submap) is tested against
the other submap's free space under several models:

- ``k``: (1), the merged submap seen from the keyframe's sensor (the check's default);
- ``s``: (1'), each scan of the submap about its own sensor;
- ``w``: (4), (1') with the returns margin of a window of `WINDOW` sectors;
- ``ks`` / ``kw``: a conflict of (1) only when (1') / (4) also calls the point free
  (a ray of the keyframe's origin that some scan really cast);
- ``kn``: (1) without the near misses (a conflict within `NEAR` [m] of the other
  submap's points is not counted).

Each (1) conflict is also put in one class: ``invented`` (not free under (1'): no
scan of the submap cast a ray through it, the keyframe-origin model's artefact),
``near`` (free under (1'), within `NEAR` of the other submap: two passes' surfaces a
little apart, the fit's or a submap's bend), ``change`` (free under (1') and farther:
something one pass saw where the other's rays went: a person, a door, glass, or a
bend beyond `NEAR`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from data import se2
from loopclosure.free_space import RangeImage, ScanFreeSpace
from loopclosure.registration import voxel_downsample

NEAR = 0.3
"""A conflict this close to the other submap's points is a near miss [m]."""
WINDOW = 8
"""Sectors either side of the returns margin of model ``w``."""
MODELS = ("k", "s", "w", "ks", "kw", "kn")


class Side:
    """One submap for the models: its points (its sensor frame [m]), KD-tree, and
    free space about the keyframe (1), about each scan (1') and with returns (4)."""

    def __init__(self, points: np.ndarray, poses: np.ndarray, ranges: np.ndarray,
                 bins: int, spread: int) -> None:
        self.points = np.asarray(points, float).reshape(-1, 2)
        self.tree = cKDTree(self.points) if len(self.points) else None
        self.image = RangeImage(self.points, bins, spread)
        self.scans = ScanFreeSpace(poses, ranges)
        self.window = ScanFreeSpace(poses, ranges, return_window=WINDOW)


def one_way(moved: np.ndarray, other: Side, tol: float, margin: float) -> dict[str, Any]:
    """Hits and, per model, conflicts of points `moved` into `other`'s frame."""
    if len(moved) == 0 or other.tree is None:
        return dict(hits=0, **{m: 0 for m in MODELS}, invented=0, near=0, change=0, far=0)
    dist, _ = other.tree.query(moved, k=1)
    hit = dist <= tol
    miss = moved[~hit]
    k = other.image.free(miss, margin)
    s = other.scans.free(miss, margin)
    w = other.window.free(miss, margin)
    near = dist[~hit] < NEAR
    rng = np.hypot(miss[:, 0], miss[:, 1])
    return dict(hits=int(hit.sum()), k=int(k.sum()), s=int(s.sum()), w=int(w.sum()),
                ks=int((k & s).sum()), kw=int((k & w).sum()), kn=int((k & ~near).sum()),
                invented=int((k & ~s).sum()), near=int((k & s & near).sum()),
                change=int((k & s & ~near).sum()), far=int((k & (rng > 8.0)).sum()))


def models_at(query: Side, cand: Side, pose: np.ndarray, tol: float, margin: float
              ) -> dict[str, float]:
    """Consistency of every model (hits / (hits + conflicts)) and the (1) conflicts'
    classes at the pose of the query in the candidate's frame, both directions."""
    t = np.asarray(pose, float).reshape(3)
    a = one_way(se2.transform_points(t, query.points), cand, tol, margin)
    b = one_way(se2.transform_points(se2.inverse(t), cand.points), query, tol, margin)
    hits = a["hits"] + b["hits"]
    out: dict[str, float] = {"hits": hits}
    for m in MODELS:
        c = a[m] + b[m]
        out[m] = hits / (hits + c) if hits + c else 0.0
    for c in ("invented", "near", "change", "far"):
        out[c] = a[c] + b[c]
    out["conflicts"] = a["k"] + b["k"]
    out["c_in_q"] = b["k"]
    return out


class ModelSides:
    """Builds and caches the `Side` of each candidate and query submap of a mapped log."""

    def __init__(self, mapper: Any, cfg: Any) -> None:
        self.mapper = mapper
        self.check = cfg.loops.check
        self.bins = self.check.search.free_bins
        self._ranges: dict[int, np.ndarray] = {}
        self._cands: dict[int, Side] = {}

    def _scan_ranges(self, keys: np.ndarray) -> np.ndarray:
        for k in keys:
            if int(k) not in self._ranges:
                self._ranges[int(k)] = RangeImage(self.mapper._keyframe(int(k)).points,
                                                  self.bins).ranges.astype(np.float32)
        return np.array([self._ranges[int(k)] for k in keys], np.float32).reshape(-1, self.bins)

    def _side(self, key: int, points: np.ndarray, voxel: float, last: int | None) -> Side:
        keys, poses = self.mapper.submap_origins(key)
        keys, poses = np.asarray(keys), np.asarray(poses, float).reshape(-1, 3)
        if last is not None:
            keys, poses = keys[keys <= last], poses[keys <= last]
        return Side(voxel_downsample(np.asarray(points, float), voxel), poses,
                    self._scan_ranges(keys), self.bins, 2)

    def candidate(self, key: int) -> Side:
        if key not in self._cands:
            self._cands[key] = self._side(key, self.mapper.submap(key),
                                          self.check.search.submap_voxel, None)
        return self._cands[key]

    def query(self, key: int, points: np.ndarray) -> Side:
        return self._side(key, points, self.check.source_voxel, key)

    def figures(self, query: Side, cand: Side, pose: np.ndarray) -> dict[str, float]:
        s = self.check.search
        return models_at(query, cand, pose, s.consistency_tolerance, s.free_margin)


REFUSALS = ("inconsistent free space", "partial overlap", "degenerate")


def _pose_error(ref: np.ndarray, q: int, m: int, rel: np.ndarray) -> tuple[float, float]:
    off = se2.between(se2.between(ref[m], ref[q]), rel)
    return float(np.hypot(off[0], off[1])), float(abs(np.degrees(off[2])))


def table(d: dict) -> None:
    """Print, for a record of ``final_precision.py record --models``: the refused checks
    at a true place (within 2 m by the reference) by refusal and cause, and each
    model's separation of the true fits (within 0.2 m / 2 deg) from the wrong ones
    (fits beyond 1 m / 5 deg of the reference's pose) among every check that
    reached the consistency test."""
    ref = d["ref"]
    rows = []
    for q, checks in d["checks"].items():
        for c in checks:
            if not c.get("models"):
                continue
            m = int(c["match"])
            place = float(np.hypot(*(ref[q, :2] - ref[m, :2])))
            err = _pose_error(ref, q, m, c["relative"])
            rows.append((q, m, place, err, c))
    print(f"\n## {d['log']}: {len(rows)} checks reached the consistency test")
    # 1. refused at a true place
    for refusal in REFUSALS[:2]:
        sel = [r for r in rows if r[2] <= 2.0 and (
            r[4]["reason"].startswith(refusal) if refusal == REFUSALS[0]
            else r[4]["reason"].startswith(REFUSALS[1:]))]
        right = [r for r in sel if r[3][0] <= 0.2 and r[3][1] <= 2.0]
        near = [r for r in sel if r not in right and r[3][0] <= 1.0 and r[3][1] <= 5.0]
        print(f"refused '{refusal}' at a true place: {len(sel)} checks "
              f"({len({r[0] for r in sel})} queries); fit right {len(right)}, "
              f"within 1 m / 5 deg {len(near)}, wrong {len(sel) - len(right) - len(near)}")
        if refusal == REFUSALS[0] and right:
            f = np.array([[r[4]["models"]["fit"][k] for k in
                           ("conflicts", "invented", "near", "change", "far", "c_in_q")]
                          for r in right], float)
            tot = f[:, 0].sum()
            print(f"  fit-right conflicts (1): {int(tot)}: invented {f[:, 1].sum() / tot:.2f}, "
                  f"near miss {f[:, 2].sum() / tot:.2f}, change {f[:, 3].sum() / tot:.2f}; "
                  f"beyond 8 m {f[:, 4].sum() / tot:.2f}; candidate's points in the query's "
                  f"free space {f[:, 5].sum() / tot:.2f}")
            dom = np.argmax(f[:, 1:4], axis=1)
            print("  pairs by their largest class: "
                  + ", ".join(f"{n} {int((dom == i).sum())}"
                              for i, n in enumerate(("invented", "near", "change"))))
            at_ref = np.array([r[4]["models"]["ref"]["k"] for r in right])
            at_fit = np.array([r[4]["models"]["fit"]["k"] for r in right])
            print(f"  (1) at the fit: median {np.median(at_fit):.3f}; "
                  f"at the reference's pose: median {np.median(at_ref):.3f}, "
                  f"passing 0.92 {int((at_ref >= 0.92).sum())} of {len(right)}")
            for r in right:
                mf = r[4]["models"]["fit"]
                print(f"    {r[0]} -> {r[1]} place {r[2]:.2f} m err {r[3][0]:.3f} m "
                      f"{r[3][1]:.2f} deg fused {r[4]['score']:.3f} " + " ".join(
                          f"{k} {mf[k]:.3f}" for k in MODELS)
                      + f" | conflicts {int(mf['conflicts'])} inv {int(mf['invented'])} "
                        f"near {int(mf['near'])} change {int(mf['change'])}")
        if refusal == REFUSALS[1]:
            for r in sel:
                print(f"    {r[0]} -> {r[1]} place {r[2]:.2f} m err {r[3][0]:.3f} m "
                      f"{r[3][1]:.2f} deg {r[4]['reason']} fitness {r[4]['figs']['fitness']:.3f}"
                      f" pinned {r[4]['figs']['pinned_length']:.1f} m "
                      f"axis_hold {r[4]['figs']['axis_hold']:.3f}")
    # 2. separation of each model
    true = [r for r in rows if r[2] <= 2.0 and r[3][0] <= 0.2 and r[3][1] <= 2.0]
    wrong = [r for r in rows if r[3][0] > 1.0 or r[3][1] > 5.0]
    print(f"separation: {len(true)} true fits, {len(wrong)} wrong")
    print("  model: true min / 5th / median | wrong 99th / max | wrong >= true 5th pct | "
          "true < wrong max")
    for k in MODELS:
        t = np.array([r[4]["models"]["fit"][k] for r in true])
        w = np.array([r[4]["models"]["fit"][k] for r in wrong])
        if len(t) == 0 or len(w) == 0:
            continue
        print(f"  {k:3s}: {t.min():.3f} / {np.percentile(t, 5):.3f} / {np.median(t):.3f} | "
              f"{np.percentile(w, 99):.3f} / {w.max():.3f} | "
              f"{int((w >= np.percentile(t, 5)).sum())} | {int((t < w.max()).sum())}")
    top = sorted(wrong, key=lambda r: -r[4]["models"]["fit"]["k"])[:5]
    for r in top:
        mf = r[4]["models"]["fit"]
        print(f"    wrong {r[0]} -> {r[1]} place {r[2]:.1f} m err {r[3][0]:.2f} m "
              f"{r[3][1]:.1f} deg {r[4]['reason'][:30]} " + " ".join(
                  f"{k} {mf[k]:.3f}" for k in MODELS))


def main() -> None:
    import argparse
    import pickle

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("files", nargs="+", help="records of final_precision.py record --models")
    for path in ap.parse_args().files:
        with open(path, "rb") as f:
            table(pickle.load(f))


if __name__ == "__main__":
    main()
