"""CPU renderer (numpy + OpenCV): textured, shaded RGB, z-depth, instance masks and per-instance coverage.

Every surface is a planar convex polygon (box faces, prism sides and caps, room walls, pictures). A frame is drawn
in two passes:
1. rasterisation: for each front-facing polygon in view (clipped at the near plane), its pixels are the pixel
   centres inside its projected edges (half-plane tests over its screen rectangle) and their exact z-depth comes
   from the plane equation
   (z = d / (a u + b v + c), linear in the pixel); a z-buffer keeps the nearest face index;
2. deferred shading: each pixel is lifted to the world with its depth, its face's texture coordinates index a
   procedural texture (4 pre-blurred levels chosen by texel footprint, so distant surfaces do not alias), tinted by
   the object's colour, lit by a directional light and a ceiling point light (Lambert), with a slow large-scale
   brightness variation and sensor noise.
Textures are stochastic (fBm noise, wood grain, weaves, tiles, pictures with shapes), so SIFT/ORB find real,
repeatable matches across frames.

Coverage for the visible fraction: while rasterising, the faces of one instance are drawn consecutively into a
stamp buffer without the z-test; the number of newly stamped pixels is the instance's unoccluded in-image area
(its silhouette if nothing else were in front). Visible pixels are those that win the z-test.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from mosaicthinker.runtime.geometry import invert
from mosaicthinker.host.synth.scene import POSTER_PATTERNS, Scene

T = 256  # texture size (texels), power of two
LEVELS = 4
NEAR = 0.05

PATTERNS = ("plaster", "wood", "fabric", "tiles", "carpet", "metal", "screen", "books", "leaves", "ceramic",
            "dark", "paint", "parquet", "ceiling") + POSTER_PATTERNS
# texels per metre of each pattern (screens and pictures are fitted to their face instead)
DENSITY = {"plaster": 110.0, "wood": 300.0, "fabric": 420.0, "tiles": 200.0, "carpet": 300.0, "metal": 260.0,
           "leaves": 300.0, "ceramic": 200.0, "dark": 300.0, "paint": 180.0, "parquet": 160.0, "ceiling": 90.0,
           "books": 400.0}


# ----------------------------------------------------------------------------- textures


def _fbm(rng: np.random.Generator, octaves=(4, 8, 16, 32, 64), gain: float = 0.55) -> np.ndarray:
    """Tileable fractal noise [T, T] in about [0, 1]."""
    out = np.zeros((T, T), np.float32)
    amp, tot = 1.0, 0.0
    for g in octaves:
        small = rng.random((g, g)).astype(np.float32)
        k = T // g  # integer upscale of a wrap-padded grid: the crop is exactly one period
        big = cv2.resize(np.pad(small, 2, mode="wrap"), ((g + 4) * k, (g + 4) * k),
                         interpolation=cv2.INTER_CUBIC)[2 * k:2 * k + T, 2 * k:2 * k + T]
        out += amp * big
        tot += amp
        amp *= gain
    out /= tot
    return (out - out.min()) / max(1e-6, float(out.max() - out.min()))


def _shapes(rng: np.random.Generator, n: int = 40) -> np.ndarray:
    img = np.full((T, T, 3), rng.uniform(0.75, 0.95), np.float32)
    for _ in range(n):
        col = tuple(float(c) for c in rng.random(3))
        k = rng.integers(3)
        p = rng.integers(0, T, 2)
        if k == 0:
            q = p + rng.integers(10, 80, 2)
            cv2.rectangle(img, (int(p[0]), int(p[1])), (int(q[0]), int(q[1])), col, -1)
        elif k == 1:
            cv2.circle(img, (int(p[0]), int(p[1])), int(rng.integers(5, 40)), col, -1)
        else:
            q = rng.integers(0, T, 2)
            cv2.line(img, (int(p[0]), int(p[1])), (int(q[0]), int(q[1])), col, int(rng.integers(2, 7)))
    return img


def make_textures(seed: int) -> np.ndarray:
    """Procedural texture atlas: [LEVELS * P * T * T, 3] uint8 (level-major, then pattern, row, column), P =
    len(PATTERNS); level k is blurred for a footprint of 2^k texels per pixel."""
    rng = np.random.default_rng([int(seed), 31337])
    yy, xx = np.mgrid[0:T, 0:T].astype(np.float32)
    pats = []
    for name in PATTERNS:
        f = _fbm(rng)
        if name in ("plaster", "ceiling", "paint"):
            g = 0.82 + 0.14 * f
            sp = rng.random((T, T)) < (0.004 if name != "ceiling" else 0.002)
            g[sp] *= 0.75
            g = cv2.GaussianBlur(g, (3, 3), 0.6) * (0.9 + 0.1 * _fbm(rng, (16, 32, 64, 128)))
            img = np.repeat(g[..., None], 3, 2)
        elif name == "wood":
            warp = 12.0 * _fbm(rng, (2, 4, 8))
            g = 0.72 + 0.18 * np.sin(2 * np.pi * (yy + warp * 4) / 32.0) + 0.12 * (_fbm(rng, (8, 32, 128)) - 0.5)
            img = np.repeat(g[..., None], 3, 2)
        elif name == "parquet":
            g = np.zeros((T, T), np.float32)
            plank = 32
            for r in range(T // plank):
                tone = rng.uniform(0.65, 1.0)
                off = int(rng.integers(0, T))
                rows = slice(r * plank, (r + 1) * plank)
                g[rows] = tone
                g[rows, (off + np.arange(T)) % T < 3] *= 0.5  # plank ends
                g[r * plank:r * plank + 2] *= 0.55
            g *= 0.8 + 0.2 * np.sin(2 * np.pi * (yy + 20 * _fbm(rng, (2, 4, 8))) / 9.0) ** 2
            g *= 0.85 + 0.3 * (_fbm(rng, (16, 64)) - 0.5)
            img = np.repeat(g[..., None], 3, 2)
        elif name == "fabric":
            weave = 0.5 + 0.5 * np.sin(2 * np.pi * xx / 4) * np.sin(2 * np.pi * yy / 4)
            g = 0.7 + 0.12 * weave + 0.3 * (_fbm(rng, (8, 16, 64)) - 0.5)
            img = np.repeat(g[..., None], 3, 2)
        elif name == "tiles":
            tile = 64
            g = np.zeros((T, T), np.float32)
            for i in range(T // tile):
                for j in range(T // tile):
                    g[i * tile:(i + 1) * tile, j * tile:(j + 1) * tile] = rng.uniform(0.7, 1.0)
            g *= 0.85 + 0.3 * (f - 0.5)
            grout = ((xx % tile) < 3) | ((yy % tile) < 3)
            g[grout] = 0.45
            img = np.repeat(g[..., None], 3, 2)
        elif name == "carpet":
            g = 0.6 + 0.4 * _fbm(rng, (32, 64, 128, 256), 0.8)
            img = np.repeat(g[..., None], 3, 2)
        elif name == "metal":
            streak = cv2.resize(np.tile(rng.random((T, 4)).astype(np.float32), (1, 3)), (3 * T, T))[:, T:2 * T]
            g = 0.8 + 0.1 * streak + 0.12 * (f - 0.5)
            img = np.repeat(g[..., None], 3, 2)
        elif name == "screen":
            img = np.stack([_fbm(rng, (2, 4, 8, 16)) for _ in range(3)], 2) * 0.8 + 0.1
            img = (0.6 * img + 0.4 * _shapes(rng, 25)).astype(np.float32)
        elif name.startswith("poster"):
            img = _shapes(rng, int(rng.integers(30, 60)))
        elif name == "books":
            img = np.zeros((T, T, 3), np.float32)
            x = 0
            while x < T:
                w = int(rng.integers(6, 20))
                img[:, x:x + w] = rng.uniform(0.15, 0.9, 3)
                img[:, x + w - 1:x + w] *= 0.4
                band = int(rng.integers(20, T - 40))
                img[band:band + 8, x + 2:x + w - 2] = 0.9
                x += w
        elif name == "leaves":
            img = np.zeros((T, T, 3), np.float32) + np.array([0.15, 0.35, 0.12], np.float32)
            for _ in range(220):
                c = (float(rng.uniform(0.1, 0.4)), float(rng.uniform(0.4, 0.9)), float(rng.uniform(0.1, 0.35)))
                p = rng.integers(0, T, 2)
                cv2.ellipse(img, (int(p[0]), int(p[1])), (int(rng.integers(4, 14)), int(rng.integers(2, 6))),
                            float(rng.uniform(0, 180)), 0, 360, c, -1)
            img /= 0.7
        elif name == "ceramic":
            g = 0.93 + 0.06 * f
            img = np.repeat(g[..., None], 3, 2)
        elif name == "dark":
            g = 0.6 + 0.4 * _fbm(rng, (16, 32, 64))
            img = np.repeat(g[..., None], 3, 2)
        else:  # pragma: no cover - every pattern is listed above
            raise ValueError(name)
        pats.append(np.clip(img, 0, 1.2))
    levels = []
    for k in range(LEVELS):
        lv = []
        for img in pats:
            if k:
                s = 0.5 * 2 ** k
                pad = int(3 * s) + 1  # wrap-around padding keeps the blurred texture tileable
                img = cv2.GaussianBlur(np.pad(img, ((pad, pad), (pad, pad), (0, 0)), mode="wrap"), (0, 0), s)
                img = img[pad:pad + T, pad:pad + T]
            lv.append(np.clip(img * 212.0, 0, 255).astype(np.uint8))
        levels.append(np.stack(lv))
    return np.stack(levels).reshape(-1, 3)


# ----------------------------------------------------------------------------- surfaces


@dataclass
class Faces:
    """All planar polygons of a scene. verts: [V, 3] world; start: [F + 1] offsets into verts; normal: [F, 3]
    unit, pointing to the side that is drawn; inst: [F] instance id (0 = room); pattern: [F]; color: [F, 3]
    float32 tint; origin, e1, e2: [F, 3] texture frame (metres); density: [F] texels per metre; offset: [F, 2]
    texels."""

    verts: np.ndarray
    start: np.ndarray
    normal: np.ndarray
    inst: np.ndarray
    pattern: np.ndarray
    color: np.ndarray
    origin: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    density: np.ndarray
    offset: np.ndarray

    def __len__(self) -> int:
        return len(self.normal)


class _FaceList:
    def __init__(self, rng: np.random.Generator):
        self.rng = rng
        self.rows: list[tuple] = []

    def add(self, poly, normal, inst, pattern, color, e1, e2, density=None):
        poly = np.asarray(poly, float)
        n = np.asarray(normal, float)
        n = n / np.linalg.norm(n)
        dens = DENSITY.get(pattern, 200.0) if density is None else density
        off = self.rng.uniform(0, T, 2) if density is None else np.zeros(2)
        self.rows.append((poly, n, inst, PATTERNS.index(pattern), color, np.asarray(e1, float),
                          np.asarray(e2, float), dens, off))

    def build(self) -> Faces:
        rows = sorted(self.rows, key=lambda r: r[2])  # instances consecutive (coverage stamping)
        counts = [len(r[0]) for r in rows]
        start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        return Faces(np.concatenate([r[0] for r in rows]), start, np.array([r[1] for r in rows]),
                     np.array([r[2] for r in rows], np.int32), np.array([r[3] for r in rows], np.int32),
                     np.array([r[4] for r in rows], np.float32),
                     np.array([r[0][0] for r in rows]), np.array([r[5] for r in rows]),
                     np.array([r[6] for r in rows]), np.array([r[7] for r in rows], np.float32),
                     np.array([r[8] for r in rows], np.float32))


def _box_faces(fl: _FaceList, lo, hi, R, t, inst, pat, col):
    for a in range(3):
        b, c = [k for k in range(3) if k != a]
        for side, val in ((-1, lo[a]), (1, hi[a])):
            q = []
            for u, v in ((lo[b], lo[c]), (hi[b], lo[c]), (hi[b], hi[c]), (lo[b], hi[c])):
                p = np.zeros(3)
                p[a], p[b], p[c] = val, u, v
                q.append(p)
            q = np.array(q) @ R.T + t
            n = np.zeros(3)
            n[a] = side
            if a == 2:
                e1, e2 = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
            else:
                h = np.zeros(3)
                h[b if b != 2 else c] = 1.0
                e1, e2 = h, np.array([0, 0, 1.0])
            fl.add(q, R @ n, inst, pat, col, R @ e1, R @ e2)


def _cyl_faces(fl: _FaceList, lo, hi, axis, sides, R, t, inst, pat, col):
    # local coordinates: (p, q) span the ellipse, w runs along the axis
    ia = {"z": (0, 1, 2), "y": (0, 2, 1), "x": (1, 2, 0)}[axis]
    cp, cq = (lo[ia[0]] + hi[ia[0]]) / 2, (lo[ia[1]] + hi[ia[1]]) / 2
    rp, rq = (hi[ia[0]] - lo[ia[0]]) / 2, (hi[ia[1]] - lo[ia[1]]) / 2
    w0, w1 = lo[ia[2]], hi[ia[2]]
    ang = np.arange(sides) * 2 * np.pi / sides + np.pi / sides
    # circumscribe so the prism's extreme coordinates reach the ellipse's box exactly at the axis directions
    k = 1.0 / math.cos(math.pi / sides)
    P = cp + rp * np.clip(k * np.cos(ang), -1, 1)
    Q = cq + rq * np.clip(k * np.sin(ang), -1, 1)

    def pt(p, q, w):
        v = np.zeros(3)
        v[ia[0]], v[ia[1]], v[ia[2]] = p, q, w
        return v
    ax = pt(0, 0, 1)
    for i in range(sides):
        j = (i + 1) % sides
        quad = np.array([pt(P[i], Q[i], w0), pt(P[j], Q[j], w0), pt(P[j], Q[j], w1), pt(P[i], Q[i], w1)])
        tang = quad[1] - quad[0]
        if np.linalg.norm(tang) < 1e-9:
            continue
        tang /= np.linalg.norm(tang)
        n = np.cross(tang, ax)
        mid = (quad[0] + quad[1]) / 2 - pt(cp, cq, w0)
        if np.dot(n, mid) < 0:
            n = -n
        fl.add(quad @ R.T + t, R @ n, inst, pat, col, R @ tang, R @ ax)
    for w, s in ((w0, -1), (w1, 1)):
        poly = np.array([pt(P[i], Q[i], w) for i in range(sides)])
        e1 = pt(1, 0, 0)
        fl.add(poly @ R.T + t, R @ (ax * s), inst, pat, col, R @ e1, R @ np.cross(ax, e1))


def build_faces(scene: Scene) -> Faces:
    """Polygons of the room (walls, floor, ceiling, pictures; instance 0) and of every object."""
    rng = np.random.default_rng([int(scene.config.seed), 4242])
    fl = _FaceList(rng)
    room = scene.room
    x, y, h = room.Lx / 2, room.Ly / 2, room.height
    wall_col = tuple(float(c) for c in rng.choice([(0.92, 0.9, 0.85), (0.85, 0.88, 0.9), (0.9, 0.85, 0.78),
                                                   (0.8, 0.86, 0.8)]))
    floor_pat = ["parquet", "tiles", "carpet"][int(rng.integers(3))]
    floor_col = {"parquet": (0.75, 0.55, 0.38), "tiles": (0.85, 0.83, 0.8), "carpet": (0.55, 0.5, 0.45)}[floor_pat]
    fl.add([[-x, -y, 0], [x, -y, 0], [x, y, 0], [-x, y, 0]], [0, 0, 1], 0, floor_pat, floor_col,
           [1, 0, 0], [0, 1, 0])
    fl.add([[-x, -y, h], [x, -y, h], [x, y, h], [-x, y, h]], [0, 0, -1], 0, "ceiling", (0.95, 0.95, 0.95),
           [1, 0, 0], [0, 1, 0])
    for mid, n, length in room.walls():
        tng = np.array([n[1], -n[0]])
        a, b = mid - tng * length / 2, mid + tng * length / 2
        fl.add([[a[0], a[1], 0], [b[0], b[1], 0], [b[0], b[1], h], [a[0], a[1], h]], [n[0], n[1], 0], 0,
               "plaster", wall_col, [tng[0], tng[1], 0], [0, 0, 1])
    for p in scene.posters:
        n = p.normal
        tng = np.array([n[1], -n[0], 0.0])
        w, hh = p.size
        c = p.center
        quad = [c - tng * w / 2 - [0, 0, hh / 2], c + tng * w / 2 - [0, 0, hh / 2],
                c + tng * w / 2 + [0, 0, hh / 2], c - tng * w / 2 + [0, 0, hh / 2]]
        fl.add(quad, n, 0, p.pattern, (1, 1, 1), tng, [0, 0, -1], density=T / max(w, hh))
    for o in scene.objects:
        R, t = o.R, o.pos
        for pr in o.prims:
            if pr.kind == "box":
                _box_faces(fl, pr.lo, pr.hi, R, t, o.id, pr.mat, pr.color)
            else:
                _cyl_faces(fl, pr.lo, pr.hi, pr.axis, pr.sides, R, t, o.id, pr.mat, pr.color)
    faces = fl.build()
    # pictures and screens: texture fitted to the face (origin at its top-left corner)
    for i in range(len(faces)):
        name = PATTERNS[faces.pattern[i]]
        if name.startswith("poster"):
            q = faces.verts[faces.start[i]:faces.start[i + 1]]
            faces.origin[i] = q[3]
            faces.e2[i] = np.array([0, 0, -1.0])
            faces.density[i] = T / max(np.linalg.norm(q[1] - q[0]), np.linalg.norm(q[3] - q[0])) * 0.999
        elif name == "screen" and abs(faces.normal[i][2]) < 0.5:
            q = faces.verts[faces.start[i]:faces.start[i + 1]]
            top = q[np.argsort(-q[:, 2])[:2]]
            faces.e1[i] = np.cross([0, 0, 1.0], faces.normal[i])
            left = top[np.argmin(top @ faces.e1[i])]
            faces.origin[i] = left
            faces.e2[i] = np.array([0, 0, -1.0])
            faces.density[i] = T / max(1e-3, np.ptp(q @ faces.e1[i])) * 0.999
            faces.offset[i] = 0
    return faces


# ----------------------------------------------------------------------------- rasterisation


def _clip_near(poly: np.ndarray, near: float) -> np.ndarray:
    """Sutherland-Hodgman clip of a camera-frame polygon [k, 3] to z >= near."""
    out = []
    k = len(poly)
    for i in range(k):
        a, b = poly[i], poly[(i + 1) % k]
        ina, inb = a[2] >= near, b[2] >= near
        if ina:
            out.append(a)
        if ina != inb:
            s = (near - a[2]) / (b[2] - a[2])
            out.append(a + s * (b - a))
    return np.array(out)


@dataclass
class RenderResult:
    """rgb: [H, W, 3] uint8; depth: [H, W] float32 metres; instances: [H, W] uint16 (0 = room);
    visible: [N + 1] visible pixels per instance id; covered: [N + 1] unoccluded in-image pixels per id."""

    rgb: np.ndarray
    depth: np.ndarray
    instances: np.ndarray
    visible: np.ndarray
    covered: np.ndarray


class Renderer:
    """Renders one scene at a fixed size and intrinsics. K: [3, 3]."""

    def __init__(self, scene: Scene, K: np.ndarray, width: int, height: int, noise_sigma: float = 2.0):
        self.scene = scene
        self.K = np.asarray(K, np.float64)
        self.W, self.H = int(width), int(height)
        self.faces = build_faces(scene)
        self.atlas = make_textures(scene.config.seed)
        self.noise_sigma = float(noise_sigma)
        self.n_inst = max([o.id for o in scene.objects], default=0)
        u = np.arange(self.W, dtype=np.float32)
        v = np.arange(self.H, dtype=np.float32)
        self._u, self._v = u, v
        fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
        self._rays = np.stack(np.broadcast_arrays(((u[None, :] - cx) / fx), ((v[:, None] - cy) / fy),
                                                  np.ones((1, 1), np.float32)), -1).reshape(-1, 3).astype(np.float32)
        self.light = np.array([0.0, 0.0, scene.room.height - 0.15], np.float32)
        ld = np.array([0.35, 0.25, 1.0], np.float32)
        self.light_dir = ld / np.linalg.norm(ld)
        f = self.faces
        self._nface = len(f)
        self._noise = (np.random.default_rng([int(scene.config.seed), 555]).standard_normal(
            self.W * self.H * 3 + 1_000_003, dtype=np.float32) * np.float32(self.noise_sigma))
        self._macro = (0.88 + 0.24 * _fbm(np.random.default_rng([int(scene.config.seed), 99]), (2, 4, 8, 16))
                       ).astype(np.float32)

    # -- pass 1
    def rasterise(self, T_wc: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """-> depth [H, W] float32 (inf where empty), face index [H, W] int32 (-1 empty), covered [N + 1]."""
        f = self.faces
        H, W = self.H, self.W
        K = self.K
        fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
        T_cw = invert(T_wc)
        Rcw, tcw = T_cw[:3, :3], T_cw[:3, 3]
        cam = T_wc[:3, 3]
        Vc = f.verts @ Rcw.T + tcw
        p0 = f.verts[f.start[:-1]]
        front = np.einsum("ij,ij->i", cam - p0, f.normal) > 1e-9
        z = Vc[:, 2]
        zmax = np.maximum.reduceat(z, f.start[:-1])
        zmin = np.minimum.reduceat(z, f.start[:-1])
        zs = np.maximum(z, NEAR)
        uu = fx * Vc[:, 0] / zs + cx
        vv = fy * Vc[:, 1] / zs + cy
        umin, umax = np.minimum.reduceat(uu, f.start[:-1]), np.maximum.reduceat(uu, f.start[:-1])
        vmin, vmax = np.minimum.reduceat(vv, f.start[:-1]), np.maximum.reduceat(vv, f.start[:-1])
        inview = (umax >= -1) & (umin <= W) & (vmax >= -1) & (vmin <= H)
        cand = np.flatnonzero(front & (zmax > NEAR) & ((zmin < NEAR) | inview))
        nc = f.normal @ Rcw.T  # normals in the camera frame
        dc = np.einsum("ij,ij->i", nc, p0 @ Rcw.T + tcw)
        zbuf = np.full((H, W), np.inf, np.float32)
        fbuf = np.full((H, W), -1, np.int32)
        stamp = np.zeros((H, W), np.int32)
        covered = np.zeros(self.n_inst + 1, np.int64)
        for i in cand:
            s, e = f.start[i], f.start[i + 1]
            if zmin[i] < NEAR:
                poly = _clip_near(Vc[s:e], NEAR)
                if len(poly) < 3:
                    continue
                pu = fx * poly[:, 0] / poly[:, 2] + cx
                pv = fy * poly[:, 1] / poly[:, 2] + cy
                zlo, zhi = float(poly[:, 2].min()), float(poly[:, 2].max())
            else:
                pu, pv = uu[s:e], vv[s:e]
                zlo, zhi = float(zmin[i]), float(zmax[i])
            x0, x1 = max(0, int(math.floor(pu.min()))), min(W, int(math.ceil(pu.max())) + 1)
            y0, y1 = max(0, int(math.floor(pv.min()))), min(H, int(math.ceil(pv.max())) + 1)
            if x1 <= x0 or y1 <= y0:
                continue
            m = self._inside(pu, pv, x0, x1, y0, y1)
            if m is None:
                continue
            n = nc[i]
            a, b = n[0] / fx, n[1] / fy
            c = n[2] - a * cx - b * cy
            denom = (a * self._u[x0:x1])[None, :] + (b * self._v[y0:y1] + c)[:, None]
            with np.errstate(divide="ignore", invalid="ignore"):
                zz = (dc[i] / denom).astype(np.float32)
            m &= zz > NEAR * 0.5
            # boundary pixels (centres just outside the polygon) extrapolate the plane: keep their depth within
            # the face's own depth range so silhouettes carry no flying points
            np.clip(zz, zlo, zhi, out=zz)
            zb = zbuf[y0:y1, x0:x1]
            # objects win depth ties against the room and earlier objects (contact lines with floor and walls)
            upd = m & (zz < (zb + np.float32(1e-3)) if f.inst[i] > 0 else zz < zb)
            zb[upd] = zz[upd]
            fbuf[y0:y1, x0:x1][upd] = i
            inst = f.inst[i]
            if inst > 0:
                st = stamp[y0:y1, x0:x1]
                new = m & (st != inst)
                covered[inst] += int(np.count_nonzero(new))
                st[new] = inst
        return zbuf, fbuf, covered

    def _inside(self, pu: np.ndarray, pv: np.ndarray, x0: int, x1: int, y0: int, y1: int) -> np.ndarray | None:
        """Pixels of the crop whose centres lie inside (or on the edge of) the convex polygon (pu, pv): [h, w]
        bool, or None when empty. Exact half-plane tests (not a generous scan fill), so that no pixel takes the
        depth of a plane extrapolated beyond its face; faces sharing an edge share its pixels (no cracks)."""
        k = len(pu)
        area = float(np.dot(pu, np.roll(pv, -1)) - np.dot(pv, np.roll(pu, -1)))
        if abs(area) < 1e-9:
            return None
        sgn = 1.0 if area > 0 else -1.0
        u = self._u[x0:x1]
        v = self._v[y0:y1]
        m = None
        for j in range(k):
            ax, ay = pu[j], pv[j]
            bx, by = pu[(j + 1) % k], pv[(j + 1) % k]
            # cross((b - a), (p - a)) * sgn >= -eps  <=>  inside the edge's half plane
            A, B = -(by - ay) * sgn, (bx - ax) * sgn
            C = -(A * ax + B * ay)
            e = (np.float32(A) * u)[None, :] + (np.float32(B) * v + np.float32(C))[:, None] >= -1e-3
            m = e if m is None else (m & e)
        return m if m.any() else None

    # -- pass 2
    def shade(self, zbuf: np.ndarray, fbuf: np.ndarray, T_wc: np.ndarray, frame_seed: int | None = None
              ) -> np.ndarray:
        """-> rgb [H, W, 3] uint8. Per-face coefficients are expressed in the camera frame once per frame, so each
        pixel needs one row gather: texture coordinates are affine in the camera-frame point z * ray."""
        f = self.faces
        fid = fbuf.reshape(-1)
        ok = fid >= 0
        z = np.where(ok, zbuf.reshape(-1), 1.0).astype(np.float32)
        fid = np.where(ok, fid, 0)
        R, t = T_wc[:3, :3], T_wc[:3, 3]
        # s(P_w) = dens * e1 . (P_w - O) + off with P_w = R P_c + t  ->  s = (dens R^T e1) . P_c + b
        ds = f.density[:, None].astype(np.float64)
        As = (f.e1 * ds) @ R
        At = (f.e2 * ds) @ R
        bs = np.einsum("ij,ij->i", f.e1 * ds, t - f.origin) + f.offset[:, 0]
        bt = np.einsum("ij,ij->i", f.e2 * ds, t - f.origin) + f.offset[:, 1]
        Nc = f.normal @ R  # camera-frame normals
        lc = (self.light - t) @ R  # light in the camera frame
        direc = np.maximum(f.normal @ self.light_dir, 0)
        tab = np.concatenate([As, bs[:, None], At, bt[:, None], Nc, (f.density / self.K[0, 0])[:, None],
                              (50.0 / f.density)[:, None], (97.0 * f.inst)[:, None], direc[:, None],
                              f.pattern[:, None].astype(np.float64), f.color], 1).astype(np.float32)
        g = np.take(tab, fid, axis=0)  # [N, 19]
        Pc = self._rays * z[:, None]
        s = np.einsum("ij,ij->i", Pc, g[:, 0:3]) + g[:, 3]
        tt = np.einsum("ij,ij->i", Pc, g[:, 4:7]) + g[:, 7]
        si = s.astype(np.int32) & (T - 1)
        ti = tt.astype(np.int32) & (T - 1)
        lvl = np.clip(np.log2(np.maximum(z * g[:, 11], 1.0)) + 0.3, 0, LEVELS - 1).astype(np.int32)
        idx = ((lvl * len(PATTERNS) + g[:, 15].astype(np.int32)) * T + ti) * T + si
        tex = np.take(self.atlas, idx, axis=0).astype(np.float32)
        mi = (s * g[:, 12]).astype(np.int32) & (T - 1)
        mj = (tt * g[:, 12] + g[:, 13]).astype(np.int32) & (T - 1)
        macro = self._macro[mj, mi]
        L = lc.astype(np.float32) - Pc
        dist = np.sqrt(np.einsum("ij,ij->i", L, L)) + 1e-6
        point = np.maximum(np.einsum("ij,ij->i", g[:, 8:11], L) / dist, 0) / (1 + (dist * (1 / 3.5)) ** 2)
        light = (0.38 + 0.22 * g[:, 14] + 0.75 * point) * macro
        rgb = tex * (g[:, 16:19] * light[:, None])
        if self.noise_sigma > 0:
            # a fixed noise field at a per-frame offset: cheap, deterministic, uncorrelated between frames
            o = (int(frame_seed or 0) * 7919) % 1_000_003
            rgb += self._noise[o:o + rgb.size].reshape(-1, 3)
        rgb[~ok] = 0
        return np.clip(rgb, 0, 255).astype(np.uint8).reshape(self.H, self.W, 3)

    def render(self, T_wc: np.ndarray, frame_seed: int | None = None) -> RenderResult:
        zbuf, fbuf, covered = self.rasterise(T_wc)
        rgb = self.shade(zbuf, fbuf, T_wc, frame_seed)
        depth = np.where(np.isfinite(zbuf), zbuf, 0).astype(np.float32)
        inst = np.where(fbuf >= 0, self.faces.inst[np.maximum(fbuf, 0)], 0).astype(np.uint16)
        visible = np.bincount(inst.reshape(-1), minlength=self.n_inst + 1)
        return RenderResult(rgb, depth, inst, visible, covered)
