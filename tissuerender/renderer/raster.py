"""Rasterisation into the G-buffer (Qian §7.2.2): project the render surface with the laparoscope's
pinhole camera and keep, per pixel, the nearest triangle and its perspective-correct barycentrics.
"""
from __future__ import annotations

import numba
import numpy as np
from numba import njit, prange

from tissuerender.renderer.camera import camera_basis


@njit(cache=True, parallel=True)
def rasterize(sx, sy, zv, tris, width, height, near, depth, tri_id, bary, bands, jittered, offsets):
    """Z-buffer raster of triangles with screen positions ``sx, sy`` and view depths ``zv``.

    Writes per pixel the nearest view depth, the triangle id and perspective-correct barycentrics
    (weights ``b_i / z_i`` renormalised). Triangles with a vertex in front of ``near`` are skipped.
    The image is split into horizontal bands rasterised in parallel; each band visits the triangles in
    the same order, so every pixel gets the same result as a serial raster (ties keep the first).
    With ``jittered``, ``offsets`` (H, W, 2) moves each pixel's sample from the centre to
    ``(i, j) + offsets[j, i]`` (in [0, 1), ``jitter_offsets``); without, the centres are sampled and ``offsets``
    is not read. (Always an array, never None: one numba signature, one compile.)
    """
    bands = max(1, min(height, bands))
    for band in prange(bands):
        row0 = band * height // bands
        row1 = (band + 1) * height // bands - 1
        _raster_rows(sx, sy, zv, tris, width, row0, row1, near, depth, tri_id, bary, jittered, offsets)


@njit(cache=True, inline="always")
def _mix64(z):
    """splitmix64's finaliser (Steele, Lea & Flood 2014): a well-mixed 64-bit hash of a counter."""
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@njit(cache=True)
def jitter_offset(seed, j, i, width):
    """Uniform (u, v) in [0, 1)^2 for pixel (j, i), from 24-bit fields of one 64-bit hash."""
    h = _mix64(np.uint64(seed) * np.uint64(0x9E3779B97F4A7C15) + np.uint64(j * width + i) + np.uint64(1))
    return ((h >> np.uint64(40)) & np.uint64(0xFFFFFF)) / 16777216.0, ((h >> np.uint64(16)) & np.uint64(0xFFFFFF)) / 16777216.0


@njit(cache=True, parallel=True)
def _fill_jitter(seed, out):
    w = out.shape[1]
    for j in prange(out.shape[0]):
        for i in range(w):
            u, v = jitter_offset(seed, j, i, w)
            out[j, i, 0] = u
            out[j, i, 1] = v


def jitter_offsets(seed: int, height: int, width: int) -> np.ndarray:
    """(H, W, 2) float32 sample offsets in [0, 1)^2, one per pixel, from a hash of the seed and pixel."""
    out = np.empty((height, width, 2), np.float32)
    _fill_jitter(int(seed) % (1 << 62), out)
    return out


@njit(cache=True)
def _raster_rows(sx, sy, zv, tris, width, row0, row1, near, depth, tri_id, bary, jittered, offsets):
    # vertices that clipping put on the near plane may land a rounding error in front of it
    limit = near * (1.0 - 1e-9)
    for t in range(tris.shape[0]):
        a, b, c = tris[t, 0], tris[t, 1], tris[t, 2]
        y_lo = min(sy[a], sy[b], sy[c])
        y_hi = max(sy[a], sy[b], sy[c])
        if y_hi < row0 or y_lo > row1 + 1:
            continue
        if zv[a] < limit or zv[b] < limit or zv[c] < limit:
            continue
        x0, y0, x1, y1, x2, y2 = sx[a], sy[a], sx[b], sy[b], sx[c], sy[c]
        area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
        if area == 0.0:
            continue
        # multiplying by 1 / area keeps every edge function's sign exactly (shared edges stay watertight)
        inv_area = 1.0 / area
        i0 = max(int(np.floor(min(x0, x1, x2))), 0)
        i1 = min(int(np.ceil(max(x0, x1, x2))), width - 1)
        j0 = max(int(np.floor(y_lo)), row0)
        j1 = min(int(np.ceil(y_hi)), row1)
        iza, izb, izc = 1.0 / zv[a], 1.0 / zv[b], 1.0 / zv[c]
        for j in range(j0, j1 + 1):
            py = j + 0.5
            for i in range(i0, i1 + 1):
                px = i + 0.5
                if jittered:
                    px = i + offsets[j, i, 0]
                    py = j + offsets[j, i, 1]
                w0 = ((x1 - px) * (y2 - py) - (x2 - px) * (y1 - py)) * inv_area
                if w0 < 0.0:
                    continue
                w1 = ((x2 - px) * (y0 - py) - (x0 - px) * (y2 - py)) * inv_area
                if w1 < 0.0:
                    continue
                w2 = 1.0 - w0 - w1
                if w2 < 0.0:
                    continue
                p0, p1, p2 = w0 * iza, w1 * izb, w2 * izc
                inv_z = p0 + p1 + p2
                z = 1.0 / inv_z
                if z < depth[j, i]:
                    depth[j, i] = z
                    tri_id[j, i] = t
                    bary[j, i, 0] = p0 * z
                    bary[j, i, 1] = p1 * z
                    bary[j, i, 2] = p2 * z


def project(points: np.ndarray, camera, width: int, height: int):
    """Screen coordinates (pixels, row 0 at the top) and view depth of ``points`` for a camera with a
    horizontal field of view ``camera.fov_deg``."""
    r, u, f = camera_basis(camera.position, camera.look_at, camera.up)
    tan_x = np.tan(np.radians(camera.fov_deg) / 2.0)
    tan_y = tan_x * height / width
    rel = np.asarray(points, float) - np.asarray(camera.position, float)
    xv, yv, zv = rel @ r, rel @ u, rel @ f
    safe = np.where(zv > 1e-12, zv, 1e-12)
    sx = (xv / safe / tan_x + 1.0) * 0.5 * width
    sy = (1.0 - yv / safe / tan_y) * 0.5 * height
    return sx, sy, zv


_CENTRES = np.full((1, 1, 2), 0.5, np.float32)  # the offsets argument when pixels sample their centres


def rasterize_objects(points: np.ndarray, triangles: np.ndarray, camera, width: int, height: int,
                      jitter_seed: int = -1):
    """(depth (H, W) view depth or inf, triangle id (H, W) or -1, perspective-correct barycentrics (H, W, 3));
    ``jitter_seed`` >= 0: each pixel samples a seeded uniform point of itself (-1: pixel centres)."""
    jittered = jitter_seed >= 0
    offsets = jitter_offsets(jitter_seed, height, width) if jittered else _CENTRES
    sx, sy, zv = project(points, camera, width, height)
    depth = np.full((height, width), np.inf)
    tri_id = np.full((height, width), -1, np.int64)
    bary = np.zeros((height, width, 3))
    if triangles.shape[0]:
        rasterize(sx, sy, zv, triangles, width, height, float(camera.near), depth, tri_id, bary,
                  4 * numba.get_num_threads(), jittered, offsets)
    far = depth > camera.far
    depth[far], tri_id[far] = np.inf, -1
    return depth, tri_id, bary


@njit(cache=True, parallel=True)
def _interpolate(P, N, T, tri_id, bary, jj, ii, cam, pos, nrm, wo, tri):
    for k in prange(jj.shape[0]):
        t = tri_id[jj[k], ii[k]]
        tri[k] = t
        a, b, c = T[t, 0], T[t, 1], T[t, 2]
        w0, w1, w2 = bary[jj[k], ii[k], 0], bary[jj[k], ii[k], 1], bary[jj[k], ii[k], 2]
        px = w0 * P[a, 0] + w1 * P[b, 0] + w2 * P[c, 0]
        py = w0 * P[a, 1] + w1 * P[b, 1] + w2 * P[c, 1]
        pz = w0 * P[a, 2] + w1 * P[b, 2] + w2 * P[c, 2]
        nx = w0 * N[a, 0] + w1 * N[b, 0] + w2 * N[c, 0]
        ny = w0 * N[a, 1] + w1 * N[b, 1] + w2 * N[c, 1]
        nz = w0 * N[a, 2] + w1 * N[b, 2] + w2 * N[c, 2]
        nn = max(np.sqrt(nx * nx + ny * ny + nz * nz), 1e-12)
        vx, vy, vz = cam[0] - px, cam[1] - py, cam[2] - pz
        vn = max(np.sqrt(vx * vx + vy * vy + vz * vz), 1e-12)
        vx, vy, vz = vx / vn, vy / vn, vz / vn
        s = 1.0 / nn
        if nx * vx + ny * vy + nz * vz < 0.0:  # seen from behind: the normal faces the viewer
            s = -s
        pos[k, 0], pos[k, 1], pos[k, 2] = px, py, pz
        nrm[k, 0], nrm[k, 1], nrm[k, 2] = nx * s, ny * s, nz * s
        wo[k, 0], wo[k, 1], wo[k, 2] = vx, vy, vz


def interpolate_gbuffer(points, normals, triangles, tri_id, bary, camera_position):
    """Per covered pixel (row-major order): pixel rows and columns, world position, unit shading normal
    turned towards the viewer, unit direction to the camera, and the triangle id."""
    jj, ii = (np.ascontiguousarray(a) for a in np.nonzero(tri_id >= 0))  # C arrays: one numba signature
    k = jj.size
    pos, n, wo = np.empty((k, 3)), np.empty((k, 3)), np.empty((k, 3))
    tri = np.empty(k, np.int64)
    _interpolate(np.ascontiguousarray(points, dtype=np.float64), np.ascontiguousarray(normals, dtype=np.float64),
                 np.ascontiguousarray(triangles, dtype=np.int64), tri_id, bary, jj, ii,
                 np.asarray(camera_position, float), pos, n, wo, tri)
    return jj, ii, pos, n, wo, tri


@njit(cache=True, parallel=True)
def _downsample(hdr, depth, ss, out, out_depth):
    inv = 1.0 / (ss * ss)
    for j in prange(out.shape[0]):
        for i in range(out.shape[1]):
            r = 0.0
            g = 0.0
            b = 0.0
            d = np.inf
            for a in range(ss):
                for c in range(ss):
                    r += hdr[j * ss + a, i * ss + c, 0]
                    g += hdr[j * ss + a, i * ss + c, 1]
                    b += hdr[j * ss + a, i * ss + c, 2]
                    d = min(d, depth[j * ss + a, i * ss + c])
            out[j, i, 0] = r * inv
            out[j, i, 1] = g * inv
            out[j, i, 2] = b * inv
            out_depth[j, i] = d


def box_downsample(hdr: np.ndarray, depth: np.ndarray, ss: int):
    """Average ss x ss blocks of a supersampled HDR image (box filter; float32 out) and keep the nearest
    depth of each block."""
    h, w = hdr.shape[0] // ss, hdr.shape[1] // ss
    out = np.empty((h, w, 3), np.float32)
    out_depth = np.empty((h, w), depth.dtype)
    _downsample(hdr, depth, ss, out, out_depth)
    return out, out_depth


@njit(cache=True, parallel=True)
def _interpolate_scalar(values, T, tri_id, bary, jj, ii, out):
    for k in prange(jj.shape[0]):
        t = tri_id[jj[k], ii[k]]
        acc = 0.0
        for c in range(3):
            b = bary[jj[k], ii[k], c]
            if b > 0.0:  # a corner with no weight cannot make 0 * inf = nan
                acc += b * values[T[t, c]]
        out[k] = acc  # inf at a weighted corner (no hit within reach) stays inf


def interpolate_vertex_scalar(values, triangles, tri_id, bary, jj, ii):
    """A per-vertex scalar at every covered raster sample (perspective-correct barycentrics)."""
    out = np.empty(jj.shape[0])
    _interpolate_scalar(np.ascontiguousarray(values, dtype=np.float64), np.ascontiguousarray(triangles, np.int64),
                        tri_id, bary, jj, ii, out)
    return out


@njit(cache=True, parallel=True)
def _material_lookup(tri, tri_mat, albedo_table, alpha_table, f0_table, mat, albedo, alpha, f0):
    for k in prange(tri.shape[0]):
        m = tri_mat[tri[k]]
        mat[k] = m
        albedo[k, 0] = albedo_table[m, 0]
        albedo[k, 1] = albedo_table[m, 1]
        albedo[k, 2] = albedo_table[m, 2]
        alpha[k] = alpha_table[m]
        f0[k] = f0_table[m]


def material_lookup(tri, tri_mat, albedo_table, alpha_table, f0_table):
    """Per G-buffer point with triangle ``tri``: material id, albedo (k, 3), roughness and F0 from the
    per-material tables, in one parallel pass (instead of four fancy-indexing gathers)."""
    k = tri.shape[0]
    mat, albedo, alpha, f0 = np.empty(k, np.int64), np.empty((k, 3)), np.empty(k), np.empty(k)
    if k:
        _material_lookup(np.ascontiguousarray(tri, np.int64), np.ascontiguousarray(tri_mat, np.int64),
                         np.ascontiguousarray(albedo_table, np.float64).reshape(-1, 3),
                         np.ascontiguousarray(alpha_table, np.float64), np.ascontiguousarray(f0_table, np.float64),
                         mat, albedo, alpha, f0)
    return mat, albedo, alpha, f0


@njit(cache=True, parallel=True)
def _scatter(radiance, jj, ii, hdr):
    for k in prange(jj.shape[0]):
        for c in range(3):
            hdr[jj[k], ii[k], c] = np.float32(max(radiance[k, c], 0.0))


def scatter_radiance(radiance, jj, ii, hdr):
    """``hdr[jj, ii] = max(radiance, 0)`` as float32 (the covered raster samples are distinct)."""
    if jj.shape[0]:
        _scatter(np.ascontiguousarray(radiance, np.float64), np.ascontiguousarray(jj, np.int64),
                 np.ascontiguousarray(ii, np.int64), hdr)
