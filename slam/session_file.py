"""The saved map: everything a later run needs to continue it (``session.npz``).

`loopclosure run --out DIR` writes ``DIR/session.npz``; `loopclosure run LOG --map DIR`
reads it back and maps the new log into it (`slam.sessions`).  A saved map holds one
or more *sessions* (one log each) that were joined into one map frame: the frame of
the first session's odometry.

Why one ``.npz``: the content is a few dozen numeric arrays (ragged ones packed as
values + offsets) and a small JSON header; numpy's zip container stores them
compressed, is read member by member with ``allow_pickle=False`` (a saved map is
data, never code), and needs no new dependency.  It is written through a temporary
file renamed over the target (`data.atomic_write`), so an interrupted write leaves
the previous file or none, never half of one.

Format, version 1 (member -> shape, units; K keyframes, S scans, E odometry and L
loop constraints, all sessions together, keyframes in key order):

- ``meta`` (uint8 bytes of UTF-8 JSON): ``{"format": "loopclosure-session",
  "version": 1, "config": {...the PipelineConfig tree...}, "sessions": [...]}``,
  a session being `SessionInfo` as a dict, oldest first;
- keyframes: ``kf_session (K,)`` session index, ``kf_stamp (K,)`` [s],
  ``kf_scan_index (K,)`` position in its log, ``kf_odom (K, 3)`` front-end pose of
  the sensor, moved into the map frame by its session's transform (only relative
  poses within a session are used: submaps), ``kf_pose (K, 3)`` optimised pose (map
  frame), ``kf_delta (K, 3)`` / ``kf_cov (K, 3, 3)`` odometry increment from the
  previous keyframe of the session and its covariance;
- each keyframe's scan: ``scan_ranges``, ``scan_angles`` (values, [m] and [rad]),
  ``scan_offsets (K+1,)``, ``scan_max_range (K,)``, ``scan_min_range (K,)``;
- each keyframe's *place scan*, the 360-degree scan its place descriptors were made
  from (`LoopClosureDetector.place_scan`; zero beams when it had none):
  ``place_ranges``, ``place_angles``, ``place_offsets``, ``place_max_range``,
  ``place_min_range``.  The descriptors are recomputed from it on load: they are a
  deterministic function of that scan and the config, and storing the matchers'
  internal objects would tie the file to their code;
- the pose graph (keys = keyframe indices; information in g2o order x, y, theta):
  ``odom_ij (E, 2)``, ``odom_z (E, 3)``, ``odom_info (E, 3, 3)``, ``loop_ij (L, 2)``,
  ``loop_z (L, 3)``, ``loop_info (L, 3, 3)`` (the loops the final optimisation kept);
- every scan: ``sc_stamp (S,)`` [s], ``sc_session (S,)``, ``sc_keyframe (S,)`` the
  keyframe it hangs from, ``sc_relative (S, 3)`` its pose in that keyframe's frame
  (so it follows the keyframe when a later session moves it), ``sc_odom (S, 3)``
  its front-end pose in the map frame.

`read_saved_map` refuses a file of another format or version, or a truncated one,
with a `DataError` naming the file.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from data.atomic_write import atomic_output
from data.errors import DataError
from data.types import Scan

Array = NDArray[np.float64]

FORMAT = "loopclosure-session"
VERSION = 1
FILE_NAME = "session.npz"
"""The saved map's file name inside a run's output folder."""

_ARRAYS = {
    "kf_session": 1, "kf_stamp": 1, "kf_scan_index": 1, "kf_odom": 2, "kf_pose": 2,
    "kf_delta": 2, "kf_cov": 3,
    "scan_ranges": 1, "scan_angles": 1, "scan_offsets": 1, "scan_max_range": 1,
    "scan_min_range": 1,
    "place_ranges": 1, "place_angles": 1, "place_offsets": 1, "place_max_range": 1,
    "place_min_range": 1,
    "odom_ij": 2, "odom_z": 2, "odom_info": 3, "loop_ij": 2, "loop_z": 2, "loop_info": 3,
    "sc_stamp": 1, "sc_session": 1, "sc_keyframe": 1, "sc_relative": 2, "sc_odom": 2,
}
"""Every array member and its number of dimensions."""


@dataclass(slots=True)
class SessionInfo:
    """One session of a saved map (the ``sessions.json`` entry of `loopclosure run`).

    Attributes:
        name: what was mapped (the log's path, or the demo's name).
        scans: scans of the session.
        keyframes: its keyframes.
        joined: it is part of the map frame (always true for the first session).
        joined_at_keyframe: the session's own keyframe index at which it was joined
            (0 for the first session; None when not joined).
        joined_after_m: odometry path length of the session when it was joined [m].
        loops: loop closures accepted between this session and the older ones.
        transform: ``[x, y, theta]`` of the session's odometry frame in the map frame
            ([m], [rad]; None when not joined).
    """

    name: str
    scans: int
    keyframes: int
    joined: bool
    joined_at_keyframe: int | None = 0
    joined_after_m: float | None = 0.0
    loops: int = 0
    transform: list[float] | None = field(default_factory=lambda: [0.0, 0.0, 0.0])

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> SessionInfo:
        return cls(**{k: d[k] for k in (
            "name", "scans", "keyframes", "joined", "joined_at_keyframe", "joined_after_m",
            "loops", "transform")})


@dataclass(slots=True)
class SavedMap:
    """The content of ``session.npz`` (module docstring): `arrays` by member name."""

    config: dict[str, Any]
    sessions: list[SessionInfo]
    arrays: dict[str, np.ndarray]

    def __post_init__(self) -> None:
        missing = [k for k in _ARRAYS if k not in self.arrays]
        if missing:
            raise ValueError(f"SavedMap lacks arrays {', '.join(missing)}")

    def __getitem__(self, name: str) -> np.ndarray:
        return self.arrays[name]

    @property
    def n_keyframes(self) -> int:
        return len(self.arrays["kf_stamp"])

    @property
    def n_scans(self) -> int:
        return len(self.arrays["sc_stamp"])

    def keyframe_scan(self, k: int) -> Scan:
        """Keyframe `k`'s scan as it was logged (stamp, ranges, angles, range limits)."""
        return _scan(self, "scan", k, float(self["kf_stamp"][k]))

    def place_scan(self, k: int) -> Scan | None:
        """The scan keyframe `k`'s place was described from; None if it had none."""
        o = self["place_offsets"]
        return None if o[k + 1] == o[k] else _scan(self, "place", k, float(self["kf_stamp"][k]))


def pack_ragged(rows: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """``(values, offsets)``: row i is ``values[offsets[i]:offsets[i + 1]]``."""
    lengths = np.array([len(r) for r in rows], dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    values = np.concatenate([np.asarray(r, float) for r in rows]) if rows else np.zeros(0)
    return values, offsets


def _scan(saved: SavedMap, prefix: str, k: int, stamp: float) -> Scan:
    o = saved[f"{prefix}_offsets"]
    lo, hi = int(o[k]), int(o[k + 1])
    return Scan(
        stamp=stamp,
        ranges=np.asarray(saved[f"{prefix}_ranges"][lo:hi], dtype=float),
        angles=np.asarray(saved[f"{prefix}_angles"][lo:hi], dtype=float),
        max_range=float(saved[f"{prefix}_max_range"][k]),
        min_range=float(saved[f"{prefix}_min_range"][k]),
    )


def write_saved_map(path: str | Path, saved: SavedMap) -> Path:
    """Write `saved` to `path` atomically (module docstring); returns the path."""
    meta = {
        "format": FORMAT, "version": VERSION, "config": saved.config,
        "sessions": [asdict(s) for s in saved.sessions],
    }
    members = {"meta": np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)}
    members.update({k: np.asarray(saved.arrays[k]) for k in _ARRAYS})
    with atomic_output(path, "wb") as f:  # streamed: no second copy of the file in memory
        np.savez_compressed(f, **members)
    return Path(path)


def read_saved_map(path: str | Path) -> SavedMap:
    """Read a saved map: a ``session.npz`` file or the run folder that holds one.

    Raises:
        DataError: missing, not a saved map, of an unknown version, or truncated.
    """
    path = Path(path)
    if path.is_dir():
        path = path / FILE_NAME
    if not path.is_file():
        raise DataError(path, "no saved map here (a `loopclosure run --out DIR` folder holds "
                        f"DIR/{FILE_NAME})")
    try:
        with np.load(path, allow_pickle=False) as z:
            if "meta" not in z.files:
                raise DataError(path, "not a loopclosure saved map (no meta member)")
            meta = json.loads(bytes(z["meta"]).decode())
            if meta.get("format") != FORMAT:
                raise DataError(
                    path, f"not a loopclosure saved map (format {meta.get('format')!r})")
            if meta.get("version") != VERSION:
                raise DataError(
                    path, f"saved map version {meta.get('version')!r} is not supported "
                    f"(this loopclosure reads version {VERSION})")
            missing = [k for k in _ARRAYS if k not in z.files]
            if missing:
                raise DataError(path, f"saved map is incomplete: no {', '.join(missing)}")
            arrays = {k: z[k] for k in _ARRAYS}
    except DataError:
        raise
    except (zipfile.BadZipFile, EOFError, OSError, ValueError, KeyError) as exc:
        raise DataError(path, f"saved map is truncated or damaged ({exc})") from None
    bad = [k for k, nd in _ARRAYS.items() if arrays[k].ndim != nd]
    if bad:
        raise DataError(path, f"saved map is damaged: wrong shape of {', '.join(bad)}")
    try:
        sessions = [SessionInfo.from_dict(s) for s in meta["sessions"]]
        return SavedMap(config=dict(meta["config"]), sessions=sessions, arrays=arrays)
    except (KeyError, TypeError) as exc:
        raise DataError(path, f"saved map header is damaged ({exc})") from None
