"""A laser-stripe scanner simulator: the set-up of the stripes paper (Section III).

Geometry (world frame, metres, z up; the table is the plane z = 0):

- The line laser sits at height `standoff` above the table and moves at constant speed
  along +x; at each camera frame it is at ``x_t`` (frames `step` apart, a random phase
  per scan).  Its fan is the vertical plane ``x = x_t``, spread along y from the laser
  origin ``L_t = (x_t, 0, standoff)``.
- The camera moves rigidly with the laser (both are on the robot arm), at the same
  height, offset by ``b = standoff * tan(alpha)`` towards -x, its optical axis through
  the table point ``(x_t, 0, 0)``: ``alpha`` is the triangulation angle between the
  laser plane and the viewing direction.  Pinhole model, no distortion: image columns
  run along +y, rows grow with height; ``focal = width * (standoff / cos(alpha)) /
  field_of_view``, principal point ``(width / 2, table_row)`` so the table line sits
  near the top of the image and taller surfaces move down.  Image 600 x 712 (rows x
  columns) as in the paper.
- The object (a `meshes.Mesh`, z up) is placed on the table as a person would put it
  under the scanner: roughly square to the sweep (a random yaw within
  `yaw_range_deg`, default +-15 degrees), turned round (yaw + 180 degrees) with
  probability `turn_probability`, shifted randomly by up to `position_jitter`, its
  lowest point at z = 0; all drawn per scan from the seed.  ``yaw_range_deg=180``
  gives any yaw.
- Working range (`fit_object`, on by default; the paper is silent, its operator sets
  the arm's distance): a tall object whose top would image below the last row, or a
  wide one that would leave the image at the sides, is scanned with the laser and
  camera raised together (standoff and field of view grow in proportion, the camera
  is rigid so the focal length stays) by 10 % steps until every vertex of the placed
  object images inside the frame with `fit_margin_px` to spare.  Objects that fit at
  the configured standoff are scanned exactly as configured.  Without it the stripes
  of such objects are clipped (their tops, the part the laser sees first, go missing).

Per laser position:

1. The laser plane cuts the mesh into 2D segments (vectorised over triangles).
2. Laser shadow: the fan is sampled by rays (`rays_per_column` per image column of
   table width); each ray keeps only its first hit (a 1D z-buffer over the fan,
   vectorised by expanding each segment over the rays it spans).
3. Camera occlusion: a lit point is dropped when the segment from it to the camera
   passes through any triangle more than 0.2 mm before the point (exact ray/triangle
   tests between each triangle and the lit points inside its projected bounding box,
   vectorised with sorted columns; triangles wholly beyond the laser plane, on the far
   side from the camera, are skipped).
4. Grazing angles: points whose surface normal is more than `grazing_deg` from the
   laser ray or from the viewing ray give no return; otherwise the reflected
   intensity is Lambertian (``reflectance * cos(incidence)``) with speckle.
5. The visible points are rendered as a laser line of Gaussian width `line_sigma_px`
   into the camera image (only the bounding box of the line is rendered), with random
   gaps (runs of dark columns) and additive pixel noise; the scanner's line detector
   (`line_detector.laser_line_positions`: threshold borders, intensity-weighted row)
   finds the line per column.
6. The stripe is the detected line on the object (the table is not part of the object
   and is not rendered unless `include_table`), pixel coordinates ``(column, row)``
   ordered by column; with `quantize` the rows are rounded to whole pixels as in the
   paper's black/white stripe images.

Output: a `StripeScan` with the ordered stripes (one per laser position that saw the
object) and a report of laser positions that cut the object but gave no stripe.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from data.errors import DataError, warn
from data.stripe_scanner.line_detector import laser_line_positions
from data.stripe_scanner.meshes import Mesh

Array = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class ScannerConfig:
    """Parameters of the simulated scanner (defaults: the paper's set-up, Section III/VI).

    Attributes:
        width, height: image size [px] (columns x rows): 712 x 600.
        standoff: height of laser and camera above the table [m] (paper: ~0.6 m).
        triangulation_deg: angle between laser plane and camera axis [deg].
        field_of_view: width of table covered by the image along the laser line [m].
        table_row: image row of the laser line on the table [px].
        step: laser advance between two frames [m] (constant speed / frame rate);
            0.8 mm gives about 150 stripes per Daily object (paper: 140 on average).
        margin: the sweep starts and ends this far beyond the object [m].
        rays_per_column: laser fan samples per image column of table width.
        line_sigma_px: Gaussian half-width of the laser line in the image [px].
        threshold: detector threshold (intensity of a head-on white surface = 1).
        pixel_noise: standard deviation of additive image noise (same unit).
        speckle: relative spread of the per-sample intensity (uniform +-).
        reflectance: range of the object's albedo, drawn per scan.
        grazing_deg: incidence (laser or view) beyond which nothing is returned [deg].
        gap_rate: probability that a gap (dark run of columns) starts at a column.
        gap_length: mean length of a gap [columns].
        yaw_range_deg: object yaw drawn uniformly in [-range, +range] per scan: the
            object is placed by hand roughly square to the sweep (180: any yaw).
        turn_probability: probability that the object is also turned round (yaw + 180
            degrees), i.e. placed the other way round.
        position_jitter: object shift drawn uniformly in [-j, j] on x and y [m].
        quantize: round rows to whole pixels (the paper's black/white images).
        include_table: also detect the line on the table (tests, figures).
        fit_object: raise the scanner until the object fits the image (module docstring).
        fit_margin_px: free border kept around the object's image by `fit_object` [px].
    """

    width: int = 712
    height: int = 600
    standoff: float = 0.60
    triangulation_deg: float = 30.0
    field_of_view: float = 0.30
    table_row: float = 40.0
    step: float = 0.0008
    margin: float = 0.002
    rays_per_column: float = 2.0
    line_sigma_px: float = 1.0
    threshold: float = 0.15
    pixel_noise: float = 0.02
    speckle: float = 0.3
    reflectance: tuple[float, float] = (0.6, 1.0)
    grazing_deg: float = 82.0
    gap_rate: float = 0.003
    gap_length: float = 3.0
    yaw_range_deg: float = 15.0
    turn_probability: float = 0.5
    position_jitter: float = 0.01
    quantize: bool = True
    include_table: bool = False
    fit_object: bool = True
    fit_margin_px: float = 4.0

    @property
    def alpha(self) -> float:
        """Triangulation angle [rad]."""
        return float(np.deg2rad(self.triangulation_deg))

    @property
    def focal(self) -> float:
        """Focal length [px]."""
        return self.width * (self.standoff / np.cos(self.alpha)) / self.field_of_view


@dataclass(slots=True)
class StripeScan:
    """One simulated scan of one object.

    Attributes:
        name: object name.
        stripes: ordered stripes, each ``(K, 2)`` float (column, row) [px], ordered by
            column; one per laser position that saw the object, in sweep order.
        positions: ``(N,)`` laser position x_t [m] of each stripe.
        frame: ``(N,)`` index of each stripe's frame among all swept frames.
        n_frames: frames that swept the object's extent.
        empty_positions: frames whose laser plane cut the object but gave no stripe.
        pose: ``(yaw [rad], tx [m], ty [m])`` of the object on the table.
        image_shape: ``(rows, columns)`` of the camera image.
        field_of_view: width of table the image covered in this scan [m] (the
            configured one unless `ScannerConfig.fit_object` raised the scanner).
        standoff: height of laser and camera in this scan [m].
    """

    name: str
    stripes: list[Array]
    positions: Array
    frame: NDArray[np.int64]
    n_frames: int
    empty_positions: int
    pose: tuple[float, float, float]
    image_shape: tuple[int, int]
    field_of_view: float = 0.30
    standoff: float = 0.60

    def binary_image(self, i: int) -> NDArray[np.bool_]:
        """The black/white image of stripe `i` (``image_shape``; True on the stripe)."""
        img = np.zeros(self.image_shape, dtype=bool)
        s = np.rint(self.stripes[i]).astype(np.int64)
        ok = (s[:, 0] >= 0) & (s[:, 0] < img.shape[1]) & (s[:, 1] >= 0) & (s[:, 1] < img.shape[0])
        img[s[ok, 1], s[ok, 0]] = True
        return img

    def range_image(self) -> Array:
        """``(n_frames, columns)`` detected row per frame and column (NaN: no line).

        Rows are frames in sweep order: a top view of the scanned surface (2.5D).
        """
        out = np.full((self.n_frames, self.image_shape[1]), np.nan)
        for f, s in zip(self.frame, self.stripes, strict=True):
            c = np.rint(s[:, 0]).astype(np.int64)
            out[f, c] = s[:, 1]
        return out

    def silhouette(self) -> NDArray[np.bool_]:
        """Scanned footprint: True where a frame saw the object in a column."""
        return np.isfinite(self.range_image())

    def height_map(self, config: ScannerConfig | None = None) -> tuple[Array, tuple[float, float]]:
        """Top view of the scanned surface in metres: ``(heights, (row_m, column_m))``.

        ``heights`` is `range_image` (frames x columns, NaN: no line) with each detected
        row turned into the height ``z`` above the table by inverting the camera model
        of the module docstring (`config`: the scanner that made the scan; its
        `triangulation_deg`, `table_row`, `width` and `step`, with this scan's
        `standoff` and `field_of_view`): a point of the laser plane at height ``z``
        images at ``v = table_row + f z sin(alpha) / (h / cos(alpha) - z cos(alpha))``,
        so ``z = dv h / (cos(alpha) (f sin(alpha) + dv cos(alpha)))`` with
        ``dv = v - table_row`` and ``h`` the standoff.  ``row_m`` is the laser step
        (the spacing of the frames along the sweep) and ``column_m`` the table width
        of one image column, ``field_of_view / width`` (the perspective shrink of
        high points across the sweep is not corrected, as in `silhouette`).
        """
        cfg = config or ScannerConfig()
        a = cfg.alpha
        h = self.standoff
        f = cfg.width * (h / np.cos(a)) / self.field_of_view
        dv = self.range_image() - cfg.table_row
        z = dv * h / (np.cos(a) * (f * np.sin(a) + dv * np.cos(a)))
        return z, (float(cfg.step), float(self.field_of_view / cfg.width))


def _rotation_z(yaw: float) -> Array:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def place_on_table(vertices: Array, yaw: float, shift: tuple[float, float]) -> Array:
    """Vertices yawed about their bounding-box centre, centred at `shift`, resting on z = 0."""
    v = np.asarray(vertices, dtype=float)
    centre = 0.5 * (v.min(axis=0) + v.max(axis=0))
    out = (v - centre) @ _rotation_z(yaw).T
    out[:, 0] += shift[0]
    out[:, 1] += shift[1]
    out[:, 2] -= out[:, 2].min()
    return out


class _Camera:
    """Pinhole camera rigidly attached to the laser; `at(x_t)` gives its centre."""

    def __init__(self, cfg: ScannerConfig) -> None:
        a = cfg.alpha
        self.cfg = cfg
        self.b = cfg.standoff * np.tan(a)
        # Rows of R are the camera axes in world coordinates (x right, y down, z forward).
        self.R = np.array([[0.0, 1.0, 0.0], [np.cos(a), 0.0, np.sin(a)],
                           [np.sin(a), 0.0, -np.cos(a)]])
        self.f = cfg.focal
        self.cx = cfg.width / 2.0
        self.cy = cfg.table_row

    def centre(self, x_t: float) -> Array:
        return np.array([x_t - self.b, 0.0, self.cfg.standoff])

    def project(self, p: Array, c: Array) -> tuple[Array, Array, Array]:
        """``(u, v, depth)`` of world points ``(..., 3)`` for camera centre `c`."""
        q = (p - c) @ self.R.T
        z = q[..., 2]
        return self.f * q[..., 0] / z + self.cx, self.f * q[..., 1] / z + self.cy, z


def _expand(lo: NDArray[np.int64], hi: NDArray[np.int64]) -> tuple[NDArray[np.int64], ...]:
    """Pairs (owner, value) for every integer value in ``[lo_i, hi_i)`` of every owner i."""
    n = np.maximum(hi - lo, 0)
    owner = np.repeat(np.arange(len(lo)), n)
    start = np.repeat(np.cumsum(n) - n, n)
    value = np.repeat(lo, n) + (np.arange(int(n.sum())) - start)
    return owner, value


def fits_image(vertices: Array, cfg: ScannerConfig) -> bool:
    """True when every vertex images inside the frame (with `fit_margin_px`) as the
    laser plane passes through it (camera centre at the vertex's x)."""
    cam = _Camera(cfg)
    v = np.asarray(vertices, dtype=float)
    c = np.column_stack([v[:, 0] - cam.b, np.zeros(len(v)), np.full(len(v), cfg.standoff)])
    q = (v - c) @ cam.R.T
    z = q[:, 2]
    if np.any(z <= 0):
        return False
    u = cam.f * q[:, 0] / z + cam.cx
    r = cam.f * q[:, 1] / z + cam.cy
    m = cfg.fit_margin_px
    return bool(np.all((u >= m) & (u <= cfg.width - 1 - m) & (r <= cfg.height - 1 - m)))


def fitted_config(vertices: Array, cfg: ScannerConfig, max_raise: float = 8.0) -> ScannerConfig:
    """`cfg`, or `cfg` with standoff and field of view raised by 10 % steps (at most
    `max_raise` times) until the placed `vertices` fit the image (module docstring)."""
    from dataclasses import replace

    if not cfg.fit_object or fits_image(vertices, cfg):
        return cfg
    factor = 1.0
    while factor < max_raise:
        factor *= 1.1
        out = replace(cfg, standoff=cfg.standoff * factor,
                      field_of_view=cfg.field_of_view * factor)
        if fits_image(vertices, out):
            return out
    return out


class _Scene:
    """The placed mesh with per-triangle data used at every laser position."""

    def __init__(self, vertices: Array, faces: NDArray[np.int64], n_object: int) -> None:
        self.v = vertices
        self.f = faces
        self.n_object = n_object  # faces beyond this index are the table
        tri = vertices[faces]  # (F, 3, 3)
        self.tri = tri
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        norm = np.linalg.norm(n, axis=1)
        self.valid = norm > 0
        self.normal = n / np.where(self.valid, norm, 1.0)[:, None]
        x0, x1, x2 = tri[:, 0, 0], tri[:, 1, 0], tri[:, 2, 0]
        self.xmin = np.minimum(np.minimum(x0, x1), x2)
        self.xmax = np.maximum(np.maximum(x0, x1), x2)


def _cross_section(scene: _Scene, x_t: float) -> tuple[Array, Array, NDArray[np.int64]]:
    """Segments of the plane ``x = x_t`` with the mesh: endpoints ``(S, 2)`` (y, z) and triangle."""
    cut = np.flatnonzero(scene.valid & (scene.xmin < x_t) & (scene.xmax > x_t))
    tri = scene.tri[cut]  # (S, 3, 3)
    side = tri[..., 0] > x_t  # (S, 3)
    a_idx = np.array([0, 1, 2])
    b_idx = np.array([1, 2, 0])
    crosses = side[:, a_idx] != side[:, b_idx]  # exactly two per cut triangle
    pa, pb = tri[:, a_idx], tri[:, b_idx]  # (S, 3 edges, 3)
    denom = pb[..., 0] - pa[..., 0]
    t = (x_t - pa[..., 0]) / np.where(crosses, denom, 1.0)
    pts = pa[..., 1:] + t[..., None] * (pb[..., 1:] - pa[..., 1:])  # (S, 3, 2)
    order = np.argsort(~crosses, axis=1, kind="stable")[:, :2]
    rows = np.arange(len(cut))[:, None]
    two = pts[rows, order]  # (S, 2, 2)
    return two[:, 0], two[:, 1], cut


def _first_hits(
    a: Array, b: Array, cfg: ScannerConfig, tau0: float, dtau: float
) -> tuple[NDArray[np.int64], Array, Array, NDArray[np.int64]]:
    """Laser shadow: for each fan ray (table intercept ``tau0 + k dtau``), its first hit.

    Returns ray index k, hit (y, z), and the segment index of every lit ray.
    """
    h = cfg.standoff
    ta = h * a[:, 0] / (h - a[:, 1])
    tb = h * b[:, 0] / (h - b[:, 1])
    lo = np.ceil((np.minimum(ta, tb) - tau0) / dtau).astype(np.int64)
    hi = np.floor((np.maximum(ta, tb) - tau0) / dtau).astype(np.int64) + 1
    seg, k = _expand(lo, hi)
    if len(seg) == 0:
        return np.zeros(0, np.int64), np.zeros(0), np.zeros(0), np.zeros(0, np.int64)
    tau = tau0 + k * dtau
    A, B = a[seg], b[seg]
    d = B - A
    den = h * d[:, 0] + tau * d[:, 1]
    s = (tau * (h - A[:, 1]) - h * A[:, 0]) / np.where(den != 0, den, 1.0)
    s = np.clip(np.where(den != 0, s, 0.0), 0.0, 1.0)
    y = A[:, 0] + s * d[:, 0]
    z = A[:, 1] + s * d[:, 1]
    # First hit along a downward ray = highest hit; sort by (ray, -z).
    order = np.lexsort((-z, k))
    k, y, z, seg = k[order], y[order], z[order], seg[order]
    first = np.r_[True, k[1:] != k[:-1]]
    return k[first], y[first], z[first], seg[first]


def _occluded(
    scene: _Scene, cam: _Camera, c: Array, p: Array, tri_of_p: NDArray[np.int64], x_t: float
) -> NDArray[np.bool_]:
    """Camera occlusion: True where the segment point -> camera crosses a triangle."""
    n = len(p)
    out = np.zeros(n, dtype=bool)
    if n == 0:
        return out
    up, vp, _ = cam.project(p, c)
    order = np.argsort(up)
    us = up[order]
    # Only triangles between the laser plane and the camera can occlude.
    cand = np.flatnonzero(scene.valid & (scene.xmin < x_t + 1e-6))
    vu, vv, vz = cam.project(scene.v, c)  # every vertex once, then gathered per triangle
    f0, f1, f2 = scene.f[cand, 0], scene.f[cand, 1], scene.f[cand, 2]
    a0, a1, a2 = vu[f0], vu[f1], vu[f2]
    b0, b1, b2 = vv[f0], vv[f1], vv[f2]
    umin, umax = np.minimum(np.minimum(a0, a1), a2), np.maximum(np.maximum(a0, a1), a2)
    vmin, vmax = np.minimum(np.minimum(b0, b1), b2), np.maximum(np.maximum(b0, b1), b2)
    keep = (vz[f0] > 0) & (vz[f1] > 0) & (vz[f2] > 0)
    keep &= (umax >= us[0]) & (umin <= us[-1]) & (vmax >= vp.min()) & (vmin <= vp.max())
    cand = cand[keep]
    tu = np.column_stack([a0[keep], a1[keep], a2[keep]])
    tv = np.column_stack([b0[keep], b1[keep], b2[keep]])
    umin, umax, vmin, vmax = umin[keep], umax[keep], vmin[keep], vmax[keep]
    lo = np.searchsorted(us, umin, side="left")
    hi = np.searchsorted(us, umax, side="right")
    ti, j = _expand(lo, hi)
    pi = order[j]
    inside_v = (vp[pi] >= vmin[ti]) & (vp[pi] <= vmax[ti]) & (cand[ti] != tri_of_p[pi])
    ti, pi = ti[inside_v], pi[inside_v]
    if len(ti) == 0:
        return out
    # Point inside the projected triangle: consistent signs of the three edge functions.
    pu, pv = up[pi], vp[pi]
    u0, u1, u2 = tu[ti, 0], tu[ti, 1], tu[ti, 2]
    v0, v1, v2 = tv[ti, 0], tv[ti, 1], tv[ti, 2]
    e0 = (u1 - u0) * (pv - v0) - (v1 - v0) * (pu - u0)
    e1 = (u2 - u1) * (pv - v1) - (v2 - v1) * (pu - u1)
    e2 = (u0 - u2) * (pv - v2) - (v0 - v2) * (pu - u2)
    inside = ((e0 >= 0) & (e1 >= 0) & (e2 >= 0)) | ((e0 <= 0) & (e1 <= 0) & (e2 <= 0))
    ti, pi = ti[inside], pi[inside]
    # Where does the ray c -> p meet the triangle's plane?  Occluded if before p.
    nrm = scene.normal[cand[ti]]
    v0w = scene.tri[cand[ti], 0]
    ray = p[pi] - c
    den = np.einsum("ij,ij->i", nrm, ray)
    num = np.einsum("ij,ij->i", nrm, v0w - c)
    ok = np.abs(den) > 1e-15
    s = np.where(ok, num / np.where(ok, den, 1.0), 2.0)
    dist = np.linalg.norm(ray, axis=1)
    blocked = (s > 0) & ((1.0 - s) * dist > 2e-4)
    out[pi[blocked]] = True
    return out


def _gap_mask(rng: np.random.Generator, width: int, rate: float, length: float) -> NDArray:
    """Columns inside random dark runs (starts with probability `rate`, geometric lengths)."""
    if rate <= 0:
        return np.zeros(width, dtype=bool)
    start = rng.random(width) < rate
    lengths = rng.geometric(1.0 / max(length, 1.0), size=width)
    end = np.where(start, np.arange(width) + lengths, -1)
    return np.maximum.accumulate(end) > np.arange(width)


def _render_and_detect(
    u: Array, v: Array, inten: Array, cfg: ScannerConfig, rng: np.random.Generator
) -> Array:
    """Render the visible laser samples into the image box they cover and detect the line."""
    sig = cfg.line_sigma_px
    col = np.rint(u).astype(np.int64)
    inside = (col >= 0) & (col < cfg.width) & (v >= -3 * sig) & (v <= cfg.height - 1 + 3 * sig)
    col, v, inten = col[inside], v[inside], inten[inside]
    if len(col) == 0:
        return np.zeros((0, 2))
    reach = int(np.ceil(3 * sig))
    r0 = max(int(np.floor(v.min())) - reach, 0)
    r1 = min(int(np.ceil(v.max())) + reach + 1, cfg.height)
    c0, c1 = int(col.min()), int(col.max()) + 1
    rows = np.arange(-reach, reach + 1)
    rr = np.rint(v).astype(np.int64)[:, None] + rows[None, :]  # (n, R)
    w = inten[:, None] * np.exp(-0.5 * ((rr - v[:, None]) / sig) ** 2) / cfg.rays_per_column
    cc = np.broadcast_to(col[:, None], rr.shape)
    ok = (rr >= r0) & (rr < r1)
    hgt, wid = r1 - r0, c1 - c0
    flat = (rr[ok] - r0) * wid + (cc[ok] - c0)
    img = np.bincount(flat, weights=w[ok], minlength=hgt * wid).reshape(hgt, wid)
    dark = _gap_mask(rng, wid, cfg.gap_rate, cfg.gap_length)
    img[:, dark] = 0.0
    if cfg.pixel_noise > 0:
        img += rng.normal(0.0, cfg.pixel_noise, img.shape)
    cols, rows_f = laser_line_positions(img, cfg.threshold)
    pts = np.column_stack([cols + c0, rows_f + r0]).astype(float)
    if cfg.quantize:
        pts[:, 1] = np.rint(pts[:, 1])
    return pts


def scan_mesh(
    mesh: Mesh,
    config: ScannerConfig | None = None,
    seed: int | np.random.Generator = 0,
) -> StripeScan:
    """Scan one mesh with the simulated laser-stripe scanner (module docstring).

    Args:
        mesh: the object, metres, z up.
        config: scanner parameters.
        seed: seed or generator for the pose, sampling phase and noise.

    Raises:
        DataError: the object gives no stripe at all (too small, outside the field of
            view, or never seen by the camera).
    """
    cfg = config or ScannerConfig()
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    yaw = float(np.deg2rad(rng.uniform(-cfg.yaw_range_deg, cfg.yaw_range_deg)))
    if rng.random() < cfg.turn_probability:
        yaw += np.pi
    shift = tuple(float(x) for x in rng.uniform(-cfg.position_jitter, cfg.position_jitter, 2))
    verts = place_on_table(mesh.vertices, yaw, shift)
    cfg = fitted_config(verts, cfg)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    n_object = len(faces)
    lo_x, hi_x = verts[:, 0].min(), verts[:, 0].max()
    if cfg.include_table:
        half = cfg.field_of_view
        table_v = np.array([[lo_x - 0.5, -half, 0.0], [hi_x + 0.5, -half, 0.0],
                            [hi_x + 0.5, half, 0.0], [lo_x - 0.5, half, 0.0]])
        faces = np.vstack([faces, np.array([[0, 1, 2], [0, 2, 3]]) + len(verts)])
        verts = np.vstack([verts, table_v])
    scene = _Scene(verts, faces, n_object)
    cam = _Camera(cfg)
    reflect = float(rng.uniform(*cfg.reflectance))
    cos_graze = np.cos(np.deg2rad(cfg.grazing_deg))
    dtau = cfg.field_of_view / (cfg.width * cfg.rays_per_column)
    phase = float(rng.uniform(0.0, cfg.step))
    x_frames = np.arange(lo_x - cfg.margin + phase, hi_x + cfg.margin, cfg.step)
    stripes: list[Array] = []
    positions: list[float] = []
    frames: list[int] = []
    empty = 0
    for fi, x_t in enumerate(x_frames):
        a, b, tri_idx = _cross_section(scene, float(x_t))
        cuts_object = bool(np.any(tri_idx < n_object))
        if len(tri_idx) == 0:
            continue
        tau0 = float(rng.uniform(0.0, dtau))
        k, y, z, seg = _first_hits(a, b, cfg, tau0 - 10.0 * cfg.field_of_view, dtau)
        tri_hit = tri_idx[seg]
        if not cfg.include_table:
            keep = tri_hit < n_object
            k, y, z, tri_hit = k[keep], y[keep], z[keep], tri_hit[keep]
        pts = _detect_frame(scene, cam, cfg, float(x_t), y, z, tri_hit, reflect, cos_graze, rng)
        if len(pts):
            stripes.append(pts)
            positions.append(float(x_t))
            frames.append(fi)
        elif cuts_object:
            empty += 1
    if not stripes:
        raise DataError(mesh.name, "the scanner saw no stripe on this object (too small, "
                        "outside the field of view, or hidden from the camera)")
    return StripeScan(mesh.name, stripes, np.array(positions), np.array(frames, dtype=np.int64),
                      len(x_frames), empty, (yaw, shift[0], shift[1]),
                      (cfg.height, cfg.width), cfg.field_of_view, cfg.standoff)


def _detect_frame(
    scene: _Scene,
    cam: _Camera,
    cfg: ScannerConfig,
    x_t: float,
    y: Array,
    z: Array,
    tri_hit: NDArray[np.int64],
    reflect: float,
    cos_graze: float,
    rng: np.random.Generator,
) -> Array:
    """Visible, returned laser samples of one frame -> detected stripe pixels."""
    if len(y) == 0:
        return np.zeros((0, 2))
    p = np.column_stack([np.full(len(y), x_t), y, z])
    laser = np.array([x_t, 0.0, cfg.standoff])
    c = cam.centre(x_t)
    nrm = scene.normal[tri_hit]
    to_laser = laser - p
    to_cam = c - p
    cos_l = np.abs(np.einsum("ij,ij->i", nrm, to_laser)) / np.linalg.norm(to_laser, axis=1)
    cos_c = np.abs(np.einsum("ij,ij->i", nrm, to_cam)) / np.linalg.norm(to_cam, axis=1)
    ret = (cos_l > cos_graze) & (cos_c > cos_graze)
    p, tri_hit, cos_l = p[ret], tri_hit[ret], cos_l[ret]
    visible = ~_occluded(scene, cam, c, p, tri_hit, x_t)
    p, cos_l = p[visible], cos_l[visible]
    if len(p) == 0:
        return np.zeros((0, 2))
    u, v, _ = cam.project(p, c)
    inten = reflect * cos_l * rng.uniform(1.0 - cfg.speckle, 1.0 + cfg.speckle, len(p))
    return _render_and_detect(u, v, inten, cfg, rng)


def scan_meshes(
    meshes: Sequence[Mesh],
    config: ScannerConfig | None = None,
    seed: int = 0,
    scans_per_object: int = 1,
) -> tuple[list[StripeScan], list[int], dict[str, str]]:
    """Scan every mesh `scans_per_object` times with independent random poses.

    Returns ``(scans, source, failed)``: the scans, the index of the mesh each came from,
    and mesh name -> reason for objects that gave no stripe (skipped).  One warning
    summarises the laser positions without stripe and the skipped objects.
    """
    rng = np.random.default_rng(seed)
    scans: list[StripeScan] = []
    source: list[int] = []
    failed: dict[str, str] = {}
    for i, mesh in enumerate(meshes):
        for _ in range(scans_per_object):
            try:
                scans.append(scan_mesh(mesh, config, rng))
                source.append(i)
            except DataError as exc:
                failed[mesh.name] = exc.message
    empty = sum(s.empty_positions for s in scans)
    frames = sum(s.n_frames for s in scans)
    if empty:
        warn(f"stripe scanner: {empty} of {frames} laser positions over "
             f"{sum(1 for s in scans if s.empty_positions)} objects cut the object but gave "
             "no stripe (shadowed, hidden or grazing)")
    if failed:
        warn(f"stripe scanner: {len(failed)} objects gave no stripe at all and were skipped "
             f"({', '.join(list(failed)[:3])}{', ...' if len(failed) > 3 else ''})")
    return scans, source, failed
