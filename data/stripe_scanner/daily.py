"""Parametric meshes of the ten classes of the stripes paper's Daily100 set.

Paper: "Stripes-based Object Matching", Section VI.A: apple, banana, book, chips bag,
chopstick, egg, orange, pear, pen and bottle cap, ten real objects each.  That set is
not public; these generators make closed triangle meshes (metres, z up, resting on the
table in a natural pose) with natural instance variation drawn from a seed, so
``daily_set(seed)`` is a Daily-like set of 10 x 10 objects for the simulated scanner.

Instance variation follows what the objects are: natural produce (apple, banana,
egg, orange, pear) varies in size and shape; the chips bags are bags of one product
and the chopsticks one set (the paper's 100 % class accuracy for both suggests
identical items), while books, pens and bottle caps are of different models (the
paper's weakest classes, 42-64 %).

Every mesh is a closed surface of sphere topology: rings of vertices between two pole
vertices (`_closed_surface`).  Shapes and the ranges their parameters are drawn from
(sizes are real-object sizes, in metres):

- apple: surface of revolution, radius 36-45 mm, height 0.82-0.95 of the width, wider
  top, stem and calyx dimples, five faint lobes, random bumps, tilted up to 20 degrees.
- orange: slightly oblate sphere, radius 35-42 mm, peel pores (hundreds of small
  dimples, 0.1-0.2 mm), a navel, tilted up to 15 degrees.
- egg: ovoid, half-length 27-31 mm, width 0.72-0.80 of the length, one end fuller,
  lying on its side.
- pear: upright revolution of a large and a small bulb joined by a neck, height
  90-115 mm, tilted up to 20 degrees.
- banana: curved tapering tube on its side, length 170-220 mm, curvature radius
  100-180 mm, thickness 32-40 mm, ridged (rounded pentagonal) cross-section.
- book: rounded box 150-240 x 100-170 x 12-44 mm with a slightly warped cover.
- chips bag: bags of one product (pillow 220 x 160 x 60 mm, +-3 %), filled 0.8-1.2
  as full, crimped seams at both ends, random wrinkles.
- chopstick: chopsticks of one set (235 mm +-1 %, 7.4 mm +-3 % thick at the back
  end, tapering to 58 %, rounded-square section).
- pen: 135-150 mm cylinder, 9-11 mm thick, round or hexagonal, conical tip, clip.
- bottle cap: 28-38 mm diameter, 10-16 mm high, knurled side, lying closed side up
  (a solid cylinder) or open side up (a cup with a 1-1.5 mm wall).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError
from data.stripe_scanner.meshes import Mesh, mesh_from_arrays

Array = NDArray[np.float64]

DAILY_CLASSES: tuple[str, ...] = (
    "apple", "banana", "book", "chips", "chopstick", "egg", "orange", "pear", "pen",
    "bottle_cap",
)


# ----------------------------------------------------------------------- mesh helpers


def _closed_surface(rings: Array, pole0: Array, pole1: Array, name: str) -> Mesh:
    """Mesh of ``(R, P, 3)`` vertex rings closed by two poles; faces oriented outward."""
    n_r, n_p, _ = rings.shape
    v = np.vstack([rings.reshape(-1, 3), pole0[None, :], pole1[None, :]])
    i, j = np.meshgrid(np.arange(n_r - 1), np.arange(n_p), indexing="ij")
    a = i * n_p + j
    b = i * n_p + (j + 1) % n_p
    c = (i + 1) * n_p + (j + 1) % n_p
    d = (i + 1) * n_p + j
    band = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3),
                           np.stack([a, c, d], -1).reshape(-1, 3)])
    jj = np.arange(n_p)
    p0, p1 = n_r * n_p, n_r * n_p + 1
    fan0 = np.column_stack([np.full(n_p, p0), (jj + 1) % n_p, jj])
    last = (n_r - 1) * n_p
    fan1 = np.column_stack([np.full(n_p, p1), last + jj, last + (jj + 1) % n_p])
    f = np.vstack([band, fan0, fan1])
    t = v[f]
    volume = np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6.0
    if volume < 0:
        f = f[:, ::-1]
    return mesh_from_arrays(v, f, name)


def _revolution(
    r: Array, z: Array, n_phi: int, modulate: Callable[[Array, Array], Array] | None = None
) -> tuple[Array, Array, Array]:
    """Rings of a surface of revolution about z from profile samples ``r[k], z[k]``.

    ``r`` and ``z`` run from pole to pole *excluding* the poles (r > 0); the poles are
    ``(0, 0, z_first_pole)`` and ``(0, 0, z_last_pole)`` given as r = 0 end samples.
    `modulate(k_index_grid, phi_grid)` multiplies the radius (ridges, lobes).
    """
    phi = np.linspace(0.0, 2 * np.pi, n_phi, endpoint=False)
    rr = r[1:-1, None] * np.ones((1, n_phi))
    if modulate is not None:
        kk = np.arange(1, len(r) - 1)[:, None] * np.ones((1, n_phi))
        rr = rr * modulate(kk, phi[None, :] * np.ones_like(rr))
    rings = np.stack([rr * np.cos(phi), rr * np.sin(phi),
                      z[1:-1, None] * np.ones((1, n_phi))], axis=-1)
    return rings, np.array([0.0, 0.0, z[0]]), np.array([0.0, 0.0, z[-1]])


def _rotate(points: Array, axis: Array, angle: float) -> Array:
    """Rodrigues rotation of ``(..., 3)`` points about a unit `axis` by `angle` [rad]."""
    k = axis / np.linalg.norm(axis)
    c, s = np.cos(angle), np.sin(angle)
    return points * c + np.cross(k, points) * s + np.outer(points @ k, k).reshape(
        points.shape) * (1 - c)


def _tilt(mesh: Mesh, rng: np.random.Generator, max_deg: float) -> Mesh:
    """Tilt about a random horizontal axis by up to `max_deg`, then rest on z = 0."""
    ang = np.deg2rad(rng.uniform(0.0, max_deg))
    az = rng.uniform(0, 2 * np.pi)
    v = _rotate(mesh.vertices, np.array([np.cos(az), np.sin(az), 0.0]), ang)
    v[:, 2] -= v[:, 2].min()
    return Mesh(v, mesh.faces, mesh.name, mesh.watertight)


def _rest(v: Array) -> Array:
    out = v.copy()
    out[:, 2] -= out[:, 2].min()
    return out


def _sphere_dirs(n_theta: int, n_phi: int) -> tuple[Array, Array, Array]:
    """Polar angles (poles excluded, cosine-spaced ends) and unit directions ``(R, P, 3)``."""
    theta = np.linspace(0.0, np.pi, n_theta + 2)[1:-1]
    phi = np.linspace(0.0, 2 * np.pi, n_phi, endpoint=False)
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    d = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1)
    return th, ph, d


def _superellipsoid(half: Array, q: float, n_theta: int, n_phi: int) -> tuple[Array, ...]:
    """Rings and poles of ``sum |x_i / h_i|^q = 1`` sampled along sphere directions."""
    _, _, d = _sphere_dirs(n_theta, n_phi)
    lam = (np.abs(d / half) ** q).sum(axis=-1) ** (-1.0 / q)
    return lam[..., None] * d, np.array([0, 0, half[2]]), np.array([0, 0, -half[2]])


def _tube(
    spine: Array, normal: Array, binormal: Array, radius: Array, n_phi: int
) -> tuple[Array, Array, Array]:
    """Rings around a spine: ``spine (S, 3)``, frames ``(S, 3)``, ``radius (S, P)``.

    The first and last spine samples are the poles (their radius is ignored).
    """
    phi = np.linspace(0.0, 2 * np.pi, n_phi, endpoint=False)
    r = radius[1:-1]
    rings = (spine[1:-1, None, :] + r[..., None] * (np.cos(phi)[None, :, None] *
             normal[1:-1, None, :] + np.sin(phi)[None, :, None] * binormal[1:-1, None, :]))
    return rings, spine[0], spine[-1]


def _ends(s: Array, cap: float) -> Array:
    """Rounded-end factor along ``s in [0, 1]``: 1 inside, quarter circle over `cap` at ends."""
    e = np.clip((np.abs(s - 0.5) - (0.5 - cap)) / cap, 0.0, 1.0)
    return np.sqrt(np.clip(1.0 - e**2, 0.0, 1.0))


# ----------------------------------------------------------------------- the classes


def apple(rng: np.random.Generator, name: str = "apple") -> Mesh:
    """An apple (see the module docstring for the parameter ranges)."""
    radius = rng.uniform(0.036, 0.045)
    hz = rng.uniform(0.82, 0.95)
    wide_top = rng.uniform(0.04, 0.14)
    d_top, d_bot = rng.uniform(0.12, 0.25), rng.uniform(0.04, 0.12)
    lobes, lobe_phase = rng.uniform(0.005, 0.025), rng.uniform(0, 2 * np.pi)
    bumps = [(rng.integers(2, 5), rng.uniform(0, 2 * np.pi), rng.uniform(0.005, 0.02))
             for _ in range(3)]
    th, ph, d = _sphere_dirs(46, 96)
    rho = 1.0 + wide_top * np.cos(th) * np.sin(th)
    rho *= 1.0 + lobes * np.cos(5 * ph + lobe_phase) * np.sin(th) ** 2
    for m, p0, amp in bumps:
        rho *= 1.0 + amp * np.cos(m * ph + p0) * np.sin(2 * th + p0)
    pts = radius * rho[..., None] * d
    pts[..., 2] *= hz
    pts[..., 2] -= radius * d_top * np.exp(-((th / 0.45) ** 2))
    pts[..., 2] += radius * d_bot * np.exp(-(((np.pi - th) / 0.4) ** 2))
    top = np.array([0, 0, radius * hz * (1 - d_top)])
    bot = np.array([0, 0, -radius * hz * (1 - d_bot)])
    return _tilt(_closed_surface(pts, top, bot, name), rng, 20.0)


def orange(rng: np.random.Generator, name: str = "orange") -> Mesh:
    """An orange with peel pores and a navel."""
    radius = rng.uniform(0.035, 0.042)
    hz = rng.uniform(0.88, 0.97)
    th, _, d = _sphere_dirs(56, 112)
    n_pores = 600
    c = rng.normal(size=(n_pores, 3))
    c /= np.linalg.norm(c, axis=1, keepdims=True)
    depth = rng.uniform(0.0025, 0.005, n_pores)
    ang2 = 2.0 * (1.0 - d.reshape(-1, 3) @ c.T)  # squared angle, small-angle form
    near = np.nonzero(ang2 < (4 * 0.03) ** 2)  # beyond 4 widths a pore adds nothing
    pores = np.bincount(near[0], weights=depth[near[1]] * np.exp(-ang2[near] / 0.03**2),
                        minlength=th.size).reshape(th.shape)
    rho = 1.0 - pores - 0.04 * np.exp(-((th / 0.15) ** 2))
    pts = radius * rho[..., None] * d
    pts[..., 2] *= hz
    top = np.array([0, 0, radius * hz * 0.96])
    bot = np.array([0, 0, -radius * hz])
    return _tilt(_closed_surface(pts, top, bot, name), rng, 15.0)


def egg(rng: np.random.Generator, name: str = "egg") -> Mesh:
    """A hen's egg lying on its side."""
    a = rng.uniform(0.027, 0.031)
    b = a * rng.uniform(0.72, 0.80)
    k = rng.uniform(0.1, 0.2)
    t = np.linspace(0.0, np.pi, 50)
    r = b * np.sin(t) * (1 + k * np.cos(t))
    z = a * np.cos(t)
    rings, p0, p1 = _revolution(r, z, 72)
    m = _closed_surface(rings, p0, p1, name)
    v = _rotate(m.vertices, np.array([0.0, 1.0, 0.0]), np.pi / 2 + rng.normal(0, 0.08))
    return Mesh(_rest(v), m.faces, name, m.watertight)


def pear(rng: np.random.Generator, name: str = "pear") -> Mesh:
    """An upright pear: large bottom bulb, small top bulb, concave neck."""
    height = rng.uniform(0.09, 0.115)
    r1 = rng.uniform(0.030, 0.037)
    r2 = r1 * rng.uniform(0.50, 0.62)
    t = np.linspace(0.0, np.pi, 70)
    z = height * (1 - np.cos(t)) / 2
    bulb1 = np.sqrt(np.clip(r1**2 - (z - r1) ** 2, 0, None))
    bulb2 = np.sqrt(np.clip(r2**2 - (z - (height - r2)) ** 2, 0, None))
    frac = np.clip((z - r1) / max(height - r1 - r2, 1e-6), 0, 1)
    neck = (r1 + (r2 - r1) * frac) * (1 - 0.12 * np.sin(np.pi * frac))
    neck = np.where((z > r1) & (z < height - r2), neck, 0.0)
    r = np.maximum(np.maximum(bulb1, bulb2), neck)
    kernel = np.exp(-0.5 * (np.arange(-4, 5) / 2.0) ** 2)
    r[1:-1] = np.convolve(np.pad(r, 4, mode="edge"), kernel / kernel.sum(), "valid")[1:-1]
    r[0] = r[-1] = 0.0
    ecc = rng.uniform(0.0, 0.04)
    rings, p0, p1 = _revolution(
        r, z, 80, lambda k, phi: 1 + ecc * np.cos(phi) * (k / len(r)))
    return _tilt(_closed_surface(rings, p0, p1, name), rng, 20.0)


def banana(rng: np.random.Generator, name: str = "banana") -> Mesh:
    """A banana lying on its side: curved, tapering, ridged."""
    length = rng.uniform(0.17, 0.22)
    rc = rng.uniform(0.10, 0.18)
    rmax = rng.uniform(0.016, 0.020)
    skew = rng.uniform(0.8, 1.25)
    n_s = 110
    s = np.linspace(0.0, 1.0, n_s)
    psi = length * (s - 0.5) / rc
    spine = np.column_stack([rc * np.sin(psi), rc * (1 - np.cos(psi)), np.zeros(n_s)])
    normal = np.column_stack([-np.sin(psi), np.cos(psi), np.zeros(n_s)])
    binormal = np.tile([0.0, 0.0, 1.0], (n_s, 1))
    prof = np.sin(np.pi * s**skew) ** 0.45 * (1 - 0.2 * s)
    phi = np.linspace(0.0, 2 * np.pi, 48, endpoint=False)
    ridge = 1 + 0.05 * np.cos(5 * phi + rng.uniform(0, 2 * np.pi))
    radius = rmax * prof[:, None] * ridge[None, :]
    rings, p0, p1 = _tube(spine, normal, binormal, radius, 48)
    rings[..., 2] *= 0.9
    m = _closed_surface(rings, p0, p1, name)
    return Mesh(_rest(m.vertices), m.faces, name, m.watertight)


def book(rng: np.random.Generator, name: str = "book") -> Mesh:
    """A closed book lying flat: rounded box with a slightly warped cover."""
    half = np.array([rng.uniform(0.075, 0.12), rng.uniform(0.05, 0.085),
                     rng.uniform(0.006, 0.022)])
    rings, p0, p1 = _superellipsoid(half, rng.uniform(10, 16), 60, 120)
    warp = rng.uniform(0.0, 0.002)
    rings[..., 2] += warp * (rings[..., 0] / half[0]) ** 2
    m = _closed_surface(rings, p0, p1, name)
    return Mesh(_rest(m.vertices), m.faces, name, m.watertight)


def chips(rng: np.random.Generator, name: str = "chips") -> Mesh:
    """A chips bag lying flat: a wrinkled pillow crimped at both ends."""
    half = np.array([0.11, 0.08, 0.03]) * rng.uniform(0.97, 1.03, 3)
    half[2] *= rng.uniform(0.8, 1.2)  # how full the bag is
    rings, p0, p1 = _superellipsoid(half, 5.0, 64, 128)
    x, y = rings[..., 0] / half[0], rings[..., 1] / half[1]
    squeeze = np.clip(1 - np.abs(x) ** 6, 0, 1) ** 0.6 * np.clip(1 - np.abs(y) ** 8, 0, 1) ** 0.25
    z = rings[..., 2] * np.maximum(squeeze, 0.02)
    for _ in range(4):
        kx, ky = rng.uniform(60, 160), rng.uniform(60, 160)
        amp = rng.uniform(0.0005, 0.0015)
        z += np.sign(z) * amp * np.sin(kx * rings[..., 0] + rng.uniform(0, 6.3)) * np.sin(
            ky * rings[..., 1] + rng.uniform(0, 6.3)) * squeeze
    rings[..., 2] = z
    p0 = p0 * np.array([0, 0, 1.0])
    p1 = p1 * np.array([0, 0, 1.0])
    m = _closed_surface(rings, p0, p1, name)
    return Mesh(_rest(m.vertices), m.faces, name, m.watertight)


def _stick(
    rng: np.random.Generator, length: float, radius_s: Array, section: Callable[[Array], Array],
    n_phi: int, name: str,
) -> Mesh:
    n_s = len(radius_s)
    s = np.linspace(0.0, 1.0, n_s)
    spine = np.column_stack([length * (s - 0.5), np.zeros(n_s), np.zeros(n_s)])
    normal = np.tile([0.0, 1.0, 0.0], (n_s, 1))
    binormal = np.tile([0.0, 0.0, 1.0], (n_s, 1))
    phi = np.linspace(0.0, 2 * np.pi, n_phi, endpoint=False) + rng.uniform(0, 2 * np.pi)
    radius = radius_s[:, None] * section(phi)[None, :]
    rings, p0, p1 = _tube(spine, normal, binormal, radius, n_phi)
    m = _closed_surface(rings, p0, p1, name)
    return Mesh(_rest(m.vertices), m.faces, name, m.watertight)


def chopstick(rng: np.random.Generator, name: str = "chopstick") -> Mesh:
    """A chopstick lying on the table: tapering, round or square section."""
    length = 0.235 * rng.uniform(0.99, 1.01)
    r0 = 0.0037 * rng.uniform(0.97, 1.03)
    q = 3.0
    s = np.linspace(0.0, 1.0, 140)
    radius = r0 * (1 - 0.42 * s) * _ends(s, 0.012)

    def section(phi: Array) -> Array:
        return 1.0 / (np.abs(np.cos(phi)) ** q + np.abs(np.sin(phi)) ** q) ** (1 / q)

    return _stick(rng, length, radius, section, 24, name)


def pen(rng: np.random.Generator, name: str = "pen") -> Mesh:
    """A ballpoint pen: round or hexagonal barrel, conical tip, clip ridge."""
    length = rng.uniform(0.135, 0.150)
    r0 = rng.uniform(0.0045, 0.0055)
    hexagonal = rng.random() < 0.5
    tip = rng.uniform(0.09, 0.14)
    s = np.linspace(0.0, 1.0, 150)
    prof = np.where(s < tip, 0.15 + 0.85 * s / tip, 1.0) * _ends(s, 0.01)
    radius = r0 * prof
    clip_a, clip_b = rng.uniform(0.6, 0.7), rng.uniform(0.9, 0.96)

    def section(phi: Array) -> Array:
        if hexagonal:
            return np.cos(np.pi / 6) / np.cos((phi % (np.pi / 3)) - np.pi / 6)
        return np.ones_like(phi)

    m = _stick(rng, length, radius, section, 36, name)
    # Clip: a ridge on one side of the barrel over [clip_a, clip_b] of the length.
    v = m.vertices.copy()
    sx = (v[:, 0] - v[:, 0].min()) / length
    ang = np.arctan2(v[:, 2] - r0, v[:, 1])
    on = (sx > clip_a) & (sx < clip_b) & (np.abs(ang - np.pi / 2) < 0.35)
    v[on, 2] += 0.0015
    v = _rotate(v - [0, 0, r0], np.array([1.0, 0, 0]), rng.uniform(0, 2 * np.pi))
    return Mesh(_rest(v), m.faces, name, m.watertight)


def bottle_cap(rng: np.random.Generator, name: str = "bottle_cap") -> Mesh:
    """A screw cap: knurled side, lying closed side up (solid) or open side up (cup)."""
    radius = rng.uniform(0.014, 0.019)
    height = rng.uniform(0.010, 0.016)
    wall = rng.uniform(0.001, 0.0015)
    ridges = int(rng.integers(24, 60))
    open_up = rng.random() < 0.5
    edge = 0.0008
    side_z = np.linspace(edge, height - edge, 14)
    if open_up:
        # Outer bottom (pole) -> side up -> rim -> inner wall down -> inner floor (pole).
        rin = radius - wall
        r = np.concatenate([[0.0], np.linspace(radius * 0.3, radius - edge, 8),
                            np.full(len(side_z), radius), [radius - wall / 2],
                            np.full(len(side_z), rin)[::-1] * 1.0,
                            np.linspace(rin - edge, rin * 0.3, 8), [0.0]])
        z = np.concatenate([[0.0], np.zeros(8), side_z, [height],
                            side_z[::-1] * (height - wall) / height + wall, np.full(8, wall),
                            [wall]])
    else:
        dome = rng.uniform(-0.0005, 0.0005)
        r = np.concatenate([[0.0], np.linspace(radius * 0.3, radius - edge, 8),
                            np.full(len(side_z), radius),
                            np.linspace(radius - edge, radius * 0.3, 8), [0.0]])
        z = np.concatenate([[0.0], np.zeros(8), side_z,
                            height + dome * (1 - (np.linspace(radius - edge, radius * 0.3, 8)
                                                  / radius) ** 2), [height + dome]])
    n_side = len(side_z)
    outer = np.zeros(len(r), dtype=bool)
    outer[9 : 9 + n_side] = True

    def knurl(k: Array, phi: Array) -> Array:
        on = outer[k.astype(int)]
        return np.where(on, 1 + 0.03 * np.clip(np.cos(ridges * phi), 0, None), 1.0)

    rings, p0, p1 = _revolution(r, z, 4 * ridges if ridges < 40 else 2 * ridges, knurl)
    m = _closed_surface(rings, p0, p1, name)
    return Mesh(_rest(m.vertices), m.faces, name, m.watertight)


GENERATORS: dict[str, Callable[[np.random.Generator, str], Mesh]] = {
    "apple": apple, "banana": banana, "book": book, "chips": chips, "chopstick": chopstick,
    "egg": egg, "orange": orange, "pear": pear, "pen": pen, "bottle_cap": bottle_cap,
}


def make_object(cls: str, rng: np.random.Generator, name: str | None = None) -> Mesh:
    """One instance of class `cls` (one of `DAILY_CLASSES`)."""
    if cls not in GENERATORS:
        raise UserError(f"unknown Daily class {cls!r}; known: {', '.join(DAILY_CLASSES)}")
    return GENERATORS[cls](rng, name or cls)


def daily_set(
    seed: int = 0, per_class: int = 10, classes: tuple[str, ...] = DAILY_CLASSES
) -> tuple[list[Mesh], list[str]]:
    """The Daily-like set: `per_class` instances of each class, names ``<class>_<NN>``.

    Returns ``(meshes, labels)`` in class order; the same seed gives the same meshes.
    """
    rng = np.random.default_rng(seed)
    meshes: list[Mesh] = []
    labels: list[str] = []
    for cls in classes:
        for i in range(per_class):
            meshes.append(make_object(cls, rng, f"{cls}_{i:02d}"))
            labels.append(cls)
    return meshes, labels
