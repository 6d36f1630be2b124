"""The town's ray-caster: numba kernels over the layout of ``town_layout``.

A ray is clipped to the box over the town (the ground grid's square, from the ground to the
tallest roof), then walks the grid's cells in order (a 2-D DDA over the ground plane); in a cell
that holds boxes and that the ray crosses below the cell's tallest roof, it tests those boxes
(slab test) and stops at the nearest hit that lies inside the cell. Past the grid, or before
any box, the ray meets the ground plane (z = 0) or the sky. So a ray costs the cells it
crosses, not the town's hundreds of boxes.

Textures are procedural (bricks, stone courses, plaster, windows with frames and mullions,
shutters, railings, shop fronts and awnings, doors, paving, asphalt with a centre line, cobbles,
grass), each fine pattern faded to its mean colour where a pixel's footprint on the surface is
larger than the pattern (the ray's distance / fx), so distant facades do not alias into noise;
pixels are additionally supersampled. Lambert shading with one sun, a sky gradient, and a light
haze with distance.

The scene travels into the kernels as one tuple (``scene_tuple``): boxes, params, cell_start,
cell_items, cell_top, kinds, noise, meta = (grid_x0, grid_y0, cell, grid_n, half, blocks, top).
Hit codes: box index >= 0, GROUND = -1, SKY = -2. Faces: 0 -x, 1 +x, 2 -y, 3 +y, 4 -z, 5 +z.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .town_layout import (BLOCK, CELL, COURTYARD, GROUND_SHOPS, MAT_BRICK, MAT_MONUMENT, MAT_PLASTER,
                          MAT_STONE, NOISE_SIZE, P_ACCENT, P_BAY, P_DARK, P_FINE, P_FRAME, P_GROUND,
                          P_HAS_WINDOWS, P_LIGHT, P_MATERIAL, P_NOISE, P_STOREY, P_WINDOW, PITCH,
                          SIDEWALK, SQUARE, STREET, Town)

GROUND = -1
SKY = -2
_EPS = 1e-9
# A direction component smaller than this is treated as this (keeps 1/d finite: the slab and
# DDA bounds become +-1e30, the parallel-ray limit).
_TINY = 1e-30
_LIGHT = (0.45 / 1.0226, -0.35 / 1.0226, 0.82 / 1.0226)   # unit sun direction
_AMBIENT = 0.45
_HAZE_M = 900.0          # distance over which the haze takes 1 - 1/e of a colour
_HORIZON = (0.84, 0.89, 0.96)
_ZENITH = (0.42, 0.60, 0.90)
_MORTAR = (0.80, 0.78, 0.72)


def scene_tuple(town: Town) -> tuple:
    """The arrays the kernels read, in the order they unpack them."""
    meta = np.array([town.grid_x0, town.grid_y0, CELL, town.grid_n, town.half, town.blocks, town.top])
    return (np.ascontiguousarray(town.boxes), np.ascontiguousarray(town.params), town.cell_start,
            town.cell_items, town.cell_top, np.ascontiguousarray(town.kinds), np.ascontiguousarray(town.noise), meta)


# --- geometry -------------------------------------------------------------------------------

@njit(cache=True, error_model="numpy")
def _safe_inverse(d):
    if abs(d) < _TINY:
        d = _TINY if d >= 0 else -_TINY
    return 1.0 / d


@njit(cache=True, error_model="numpy")
def _hit_box(boxes, k, ox, oy, oz, ix, iy, iz):
    """Entry distance of the ray into box k (inf on a miss or when the entry is behind), face."""
    tx0 = (boxes[k, 0] - ox) * ix
    tx1 = (boxes[k, 3] - ox) * ix
    ty0 = (boxes[k, 1] - oy) * iy
    ty1 = (boxes[k, 4] - oy) * iy
    tz0 = (boxes[k, 2] - oz) * iz
    tz1 = (boxes[k, 5] - oz) * iz
    nx, far_x = min(tx0, tx1), max(tx0, tx1)
    ny, far_y = min(ty0, ty1), max(ty0, ty1)
    nz, far_z = min(tz0, tz1), max(tz0, tz1)
    enter = max(nx, max(ny, nz))
    leave = min(far_x, min(far_y, far_z))
    if enter > leave or enter <= _EPS:
        return np.inf, -1
    if enter == nx:
        face = 0 if ix > 0 else 1
    elif enter == ny:
        face = 2 if iy > 0 else 3
    else:
        face = 4 if iz > 0 else 5
    return enter, face


@njit(cache=True, error_model="numpy")
def trace_ray(ox, oy, oz, dx, dy, dz, scene):
    """Nearest hit of the ray o + t d (d need not be unit; t is in units of |d|).
    -> (t, box index or GROUND or SKY, face)."""
    boxes, _, cell_start, cell_items, cell_top, _, _, meta = scene
    gx0, gy0, cell, n, top = meta[0], meta[1], meta[2], int(meta[3]), meta[6]
    t_ground = np.inf
    if dz < -_TINY:
        t_ground = -oz / dz
    ix, iy, iz = _safe_inverse(dx), _safe_inverse(dy), _safe_inverse(dz)
    # Clip the ray to the town's box: [gx0, gx0 + n cell] x [gy0, ...] x [0, top].
    gx1, gy1 = gx0 + n * cell, gy0 + n * cell
    ta, tb = (gx0 - ox) * ix, (gx1 - ox) * ix
    t0, t1 = min(ta, tb), max(ta, tb)
    ta, tb = (gy0 - oy) * iy, (gy1 - oy) * iy
    t0, t1 = max(t0, min(ta, tb)), min(t1, max(ta, tb))
    ta, tb = (0.0 - oz) * iz, (top - oz) * iz
    t0, t1 = max(t0, min(ta, tb)), min(t1, max(ta, tb))
    t0 = max(t0, 0.0)
    t1 = min(t1, t_ground)
    if t0 < t1:
        # Start cell, clamped against rounding at the grid's edge.
        px, py = ox + t0 * dx, oy + t0 * dy
        cx = min(n - 1, max(0, int(math.floor((px - gx0) / cell))))
        cy = min(n - 1, max(0, int(math.floor((py - gy0) / cell))))
        step_x = 1 if dx > 0 else -1
        step_y = 1 if dy > 0 else -1
        next_x = (gx0 + (cx + (1 if step_x > 0 else 0)) * cell - ox) * ix
        next_y = (gy0 + (cy + (1 if step_y > 0 else 0)) * cell - oy) * iy
        delta_x = cell * abs(ix)
        delta_y = cell * abs(iy)
        t_enter = t0
        while True:
            t_exit = min(min(next_x, next_y), t1)
            c = cy * n + cx
            if cell_top[c] > 0.0:
                z_low = min(oz + dz * t_enter, oz + dz * t_exit)
                if z_low <= cell_top[c]:
                    best, best_k, best_face = np.inf, -1, -1
                    for m in range(cell_start[c], cell_start[c + 1]):
                        k = cell_items[m]
                        t, face = _hit_box(boxes, k, ox, oy, oz, ix, iy, iz)
                        if t < best:
                            best, best_k, best_face = t, k, face
                    # A hit beyond this cell may hide behind a box of a later cell.
                    if best <= t_exit + 1e-7:
                        return best, best_k, best_face
            if t_exit >= t1:
                break
            if next_x < next_y:
                cx += step_x
                if cx < 0 or cx >= n:
                    break
                t_enter = next_x
                next_x += delta_x
            else:
                cy += step_y
                if cy < 0 or cy >= n:
                    break
                t_enter = next_y
                next_y += delta_y
    if t_ground < np.inf:
        return t_ground, GROUND, 5
    return np.inf, SKY, -1


# --- textures -------------------------------------------------------------------------------

@njit(cache=True)
def _frac(x):
    return x - math.floor(x)


@njit(cache=True)
def _clamp01(x):
    return min(1.0, max(0.0, x))


@njit(cache=True)
def _detail(size, footprint):
    """1 where a pattern of ``size`` m is resolved (pixel footprint <= size / 2), 0 where a
    pixel covers a whole period (footprint >= size), linear between."""
    return _clamp01(2.0 - 2.0 * footprint / size)


@njit(cache=True)
def _noise(noise, u, v):
    """Bilinear, tiling value noise at grid coordinates u, v: in [0, 1]."""
    u0, v0 = math.floor(u), math.floor(v)
    fu, fv = u - u0, v - v0
    i0, j0 = int(u0) % NOISE_SIZE, int(v0) % NOISE_SIZE
    i1, j1 = (i0 + 1) % NOISE_SIZE, (j0 + 1) % NOISE_SIZE
    a = noise[j0, i0] * (1 - fu) + noise[j0, i1] * fu
    b = noise[j1, i0] * (1 - fu) + noise[j1, i1] * fu
    return a * (1 - fv) + b * fv


@njit(cache=True)
def _fractal(noise, u, v):
    return 0.65 * _noise(noise, u, v) + 0.35 * _noise(noise, 4.1 * u + 17.0, 4.1 * v + 5.0)


@njit(cache=True)
def _mix(a0, a1, a2, b0, b1, b2, t):
    return a0 + (b0 - a0) * t, a1 + (b1 - a1) * t, a2 + (b2 - a2) * t


@njit(cache=True)
def _wall(p, u, v, noise, fp):
    """The bare wall (no openings) of a building with parameters p at facade coordinates u
    (along, m) and v (height, m): -> rgb."""
    material = int(p[P_MATERIAL])
    lr, lg, lb = p[P_LIGHT], p[P_LIGHT + 1], p[P_LIGHT + 2]
    dr, dg, db = p[P_DARK], p[P_DARK + 1], p[P_DARK + 2]
    seed = p[P_NOISE]
    grain = 0.88 + 0.22 * _fractal(noise, 3.0 * u + seed, 3.0 * v)
    if material == MAT_BRICK:
        row = math.floor(v / 0.2)
        shifted = u + 0.2 * (row % 2)
        tint = _noise(noise, math.floor(shifted / 0.4) * 3.7 + seed, row * 2.3)
        tint = 0.5 + (tint - 0.5) * _detail(0.4, fp)
        r, g, b = _mix(dr, dg, db, lr, lg, lb, tint)
        mortar_mean = 0.18
        mr, mg, mb = _mix(r, g, b, _MORTAR[0], _MORTAR[1], _MORTAR[2], mortar_mean)
        is_mortar = _frac(v / 0.2) < 0.12 or _frac(shifted / 0.4) < 0.06
        d = _detail(0.1, fp)
        if is_mortar:
            r, g, b = _mix(mr, mg, mb, _MORTAR[0], _MORTAR[1], _MORTAR[2], d)
        else:
            r, g, b = _mix(mr, mg, mb, r, g, b, d)
    elif material == MAT_STONE:
        course = math.floor(v / 0.5)
        shifted = u + 0.3 * (course % 3)
        tint = _noise(noise, math.floor(shifted / 0.9) * 5.1 + seed, course * 1.7 + 40.0)
        tint = 0.5 + (tint - 0.5) * _detail(0.9, fp)
        r, g, b = _mix(lr * 0.9, lg * 0.9, lb * 0.9, lr, lg, lb, tint)
        joint = _frac(v / 0.5) < 0.06 or _frac(shifted / 0.9) < 0.035
        d = _detail(0.12, fp) if joint else 0.0
        r, g, b = _mix(r, g, b, dr, dg, db, d * 0.8 + (1 - _detail(0.12, fp)) * 0.07)
    elif material == MAT_PLASTER:
        t = _clamp01(0.2 + 0.8 * _fractal(noise, 0.35 * u + seed, 0.35 * v + 9.0))
        r, g, b = _mix(dr, dg, db, lr, lg, lb, t)
        # A string course (a lighter band) at every floor line.
        storey = p[P_STOREY]
        band = v > 1.0 and abs(v - storey * math.floor(v / storey + 0.5)) < 0.12
        if band:
            r, g, b = min(1.0, r * 1.12), min(1.0, g * 1.12), min(1.0, b * 1.12)
    else:  # monument stone: smooth with blotches
        t = _fractal(noise, 1.5 * u + seed, 1.5 * v)
        r, g, b = _mix(dr, dg, db, lr, lg, lb, 0.35 + 0.65 * t)
    return r * grain, g * grain, b * grain


@njit(cache=True)
def _glass(v0, v1, v, shade):
    t = _clamp01((v - v0) / max(v1 - v0, 1e-6))
    r, g, b = _mix(0.10, 0.14, 0.22, 0.44, 0.54, 0.64, t)
    return r * shade, g * shade, b * shade


@njit(cache=True)
def _shop_front(p, u, v, cu, bay, top, r, g, b, shade, fp):
    """A shop window across the bay under a striped awning in the accent colour; the wall
    (r, g, b) elsewhere."""
    if abs(cu) < 0.44 * bay and top - 0.45 < v < top:
        stripe = _frac(u / 0.5) < 0.5
        return _mix(0.95, 0.93, 0.88, p[P_ACCENT], p[P_ACCENT + 1], p[P_ACCENT + 2],
                    0.5 + (0.5 if stripe else -0.5) * _detail(0.5, fp))
    if abs(cu) < 0.40 * bay and 0.45 < v < top - 0.5:
        if abs(cu) > 0.40 * bay - 0.08 or abs(v - 0.5) < 0.05:
            return _mix(r, g, b, p[P_FRAME], p[P_FRAME + 1], p[P_FRAME + 2], _detail(0.12, fp) * 0.8 + 0.2)
        return _glass(0.45, top - 0.5, v, shade * 0.8)
    return r, g, b


@njit(cache=True)
def _door(p, cu, v, r, g, b, fp):
    """A planked door 1.2 m wide in the accent colour; the wall (r, g, b) beside it."""
    if abs(cu) < 0.6 and v < 2.3:
        plank = _frac(cu / 0.15) < 0.5
        s = 0.7 * (1.0 + (0.12 if plank else -0.12) * _detail(0.15, fp))
        return p[P_ACCENT] * s, p[P_ACCENT + 1] * s, p[P_ACCENT + 2] * s
    return r, g, b


@njit(cache=True)
def _shutters_and_railing(p, u, cu, cv, half_w, v0, v1, storey_h, inside, r, g, b, shade, fp):
    """Slatted shutters beside a window and a railing across its lower part: fine, recurring
    detail only close views resolve. -> (drawn, rgb); not drawn outside them."""
    if half_w <= abs(cu) < 1.55 * half_w and v0 < cv < v1:
        slat = _frac(cv / 0.08) < 0.5
        s = 1.0 + (0.2 if slat else -0.2) * _detail(0.08, fp)
        return True, p[P_ACCENT] * s, p[P_ACCENT + 1] * s, p[P_ACCENT + 2] * s
    rail_top = v0 + 0.35 * storey_h
    if abs(cu) < 1.1 * half_w and v0 - 0.05 < cv < rail_top + 0.05:
        if abs(cv - rail_top) < 0.05:
            r, g, b = _mix(r, g, b, 0.08, 0.08, 0.10, 0.9 * _detail(0.1, fp) + 0.1)
            return True, r, g, b
        if inside:
            r, g, b = _glass(v0, v1, cv, shade)
        d = _detail(0.12, fp)
        bar = _frac(u / 0.12) < 0.3
        r, g, b = _mix(r, g, b, 0.08, 0.08, 0.10, (d if bar else 0.0) + (1 - d) * 0.3)
        return True, r, g, b
    return False, r, g, b


@njit(cache=True)
def _window(p, cu, cv, half_w, v0, v1, shade, fp):
    """Glass with a frame around it and a cross mullion, at (cu, cv) inside the window."""
    edge = min(half_w - abs(cu), min(cv - v0, v1 - cv))
    mullion = min(abs(cu), abs(cv - (v0 + 0.62 * (v1 - v0))))
    gr, gg, gb = _glass(v0, v1, cv, shade)
    fine = _detail(0.12, fp)
    amount = fine + (1 - fine) * 0.25 if edge < 0.08 or mullion < 0.035 else (1 - fine) * 0.25
    return _mix(gr, gg, gb, p[P_FRAME], p[P_FRAME + 1], p[P_FRAME + 2], amount)


@njit(cache=True)
def _facade(p, u, v, length, height, noise, fp):
    """Albedo of a building's wall at facade coordinates u in [0, length] (left to right seen
    from outside) and v in [0, height] above the building's base: -> rgb."""
    r, g, b = _wall(p, u, v, noise, fp)
    if p[P_HAS_WINDOWS] < 0.5:
        return r, g, b
    storey_h = p[P_STOREY]                    # >= 3 m
    storeys = max(1, int(math.floor((height - 0.8) / storey_h + 0.5)))
    bays = max(1, int(math.floor(length / p[P_BAY])))
    bay = length / bays                       # boxes are longer than 0
    bay_index = min(bays - 1, int(math.floor(u / bay)))
    cu = u - (bay_index + 0.5) * bay          # -bay/2 .. bay/2 across a bay
    storey = int(math.floor(v / storey_h))
    cv = v - storey * storey_h                # 0 .. storey_h within a storey
    if storey >= storeys:
        # The parapet above the top storey, with a shadow line under its cornice.
        if v - storeys * storey_h < 0.12:
            return r * 0.55, g * 0.55, b * 0.55
        return min(1.0, r * 1.08), min(1.0, g * 1.08), min(1.0, b * 1.08)
    if v < 0.35:   # plinth
        s = 0.8 + 0.3 * _noise(noise, 8.0 * u + p[P_NOISE], 8.0 * v)
        return 0.38 * s, 0.38 * s, 0.40 * s
    shade = 0.85 + 0.3 * _noise(noise, bay_index * 7.3 + p[P_NOISE], storey * 3.1)
    if storey == 0:
        if p[P_GROUND] == GROUND_SHOPS:
            return _shop_front(p, u, v, cu, bay, 0.92 * storey_h, r, g, b, shade, fp)
        if bay_index % 3 == 1 or bays == 1:
            return _door(p, cu, v, r, g, b, fp)
        v0, v1 = 0.9, 0.9 + 0.5 * storey_h
    else:
        v0, v1 = 0.28 * storey_h, 0.84 * storey_h
    half_w = min(0.5 * p[P_WINDOW] * bay, 0.9)
    inside = abs(cu) < half_w and v0 < cv < v1
    if p[P_FINE] > 0.5 and storey >= 1:
        drawn, sr, sg, sb = _shutters_and_railing(p, u, cu, cv, half_w, v0, v1, storey_h, inside, r, g, b,
                                                  shade, fp)
        if drawn:
            return sr, sg, sb
    if not inside:
        return r, g, b
    return _window(p, cu, cv, half_w, v0, v1, shade, fp)


@njit(cache=True)
def _roof(p, box, x, y, noise, fp):
    """Flat roof: gravel, with the wall's colour along a 0.5 m parapet rim."""
    rim = min(min(x - box[0], box[3] - x), min(y - box[1], box[4] - y))
    if rim < 0.5 and p[P_MATERIAL] != MAT_MONUMENT:
        return p[P_LIGHT] * 0.95, p[P_LIGHT + 1] * 0.95, p[P_LIGHT + 2] * 0.95
    t = _fractal(noise, 1.3 * x + p[P_NOISE], 1.3 * y)
    if p[P_MATERIAL] == MAT_MONUMENT:
        return _mix(p[P_DARK], p[P_DARK + 1], p[P_DARK + 2], p[P_LIGHT], p[P_LIGHT + 1], p[P_LIGHT + 2], t)
    return _mix(0.40, 0.40, 0.42, 0.62, 0.61, 0.60, t)


@njit(cache=True)
def _ground(x, y, kinds, noise, half, blocks, fp):
    """Albedo of the ground at (x, y): streets, sidewalks, squares, yards, fields outside."""
    if abs(x) > half or abs(y) > half:
        t = _fractal(noise, 0.25 * x, 0.25 * y + 31.0)
        return _mix(0.30, 0.40, 0.22, 0.48, 0.52, 0.30, t)
    gx, gy = x + half, y + half
    kx, ky = int(math.floor(gx / PITCH)), int(math.floor(gy / PITCH))
    lx, ly = gx - kx * PITCH, gy - ky * PITCH
    street_x, street_y = lx < STREET, ly < STREET     # in a street running along y / along x
    asphalt_t = _fractal(noise, 1.1 * x + 3.0, 1.1 * y + 7.0)
    ar, ag, ab = _mix(0.21, 0.21, 0.23, 0.35, 0.35, 0.36, asphalt_t)
    if street_x and street_y:
        return ar, ag, ab
    if street_x or street_y:
        lateral, along = (lx, y) if street_x else (ly, x)
        if lateral < SIDEWALK or lateral > STREET - SIDEWALK:
            edge = min(abs(lateral - SIDEWALK), abs(lateral - (STREET - SIDEWALK)))
            if edge < 0.15:   # kerb stones
                return 0.70, 0.70, 0.68
            tint = _noise(noise, math.floor(along / 0.6) * 2.9 + 5.0, math.floor(lateral / 0.6) * 1.3)
            r, g, b = _mix(0.58, 0.57, 0.54, 0.72, 0.71, 0.68, 0.5 + (tint - 0.5) * _detail(0.6, fp))
            joint = _frac(along / 0.6) < 0.05 or _frac(lateral / 0.6) < 0.05
            d = _detail(0.1, fp)
            return _mix(r, g, b, 0.40, 0.40, 0.40, (d if joint else 0.0) * 0.8 + (1 - d) * 0.08)
        if abs(lateral - STREET / 2) < 0.08 and _frac(along / 6.0) < 0.5:
            return _mix(ar, ag, ab, 0.92, 0.92, 0.88, _detail(0.16, fp) * 0.9 + 0.1)
        return ar, ag, ab
    kx, ky = min(kx, blocks - 1), min(ky, blocks - 1)
    kind = kinds[kx, ky]
    bx, by = lx - STREET, ly - STREET                 # 0 .. BLOCK inside the block
    if kind == SQUARE:
        tone = (math.floor(bx / 1.2) + math.floor(by / 1.2)) % 2
        d = _detail(1.2, fp)
        t = 0.5 + (tone - 0.5) * d
        r, g, b = _mix(0.66, 0.62, 0.56, 0.82, 0.78, 0.70, t)
        s = 0.9 + 0.15 * _fractal(noise, 2.0 * x, 2.0 * y)
        return r * s, g * s, b * s
    if kind == COURTYARD:
        cx, cy = bx - BLOCK / 2, by - BLOCK / 2
        if cx * cx + cy * cy < 16.0:   # a round lawn in the middle of the yard
            t = _fractal(noise, 3.0 * x + 11.0, 3.0 * y)
            return _mix(0.22, 0.42, 0.16, 0.42, 0.58, 0.26, t)
        tint = _noise(noise, math.floor(x / 0.25) * 1.7, math.floor(y / 0.25) * 2.3 + 19.0)
        r, g, b = _mix(0.45, 0.42, 0.38, 0.66, 0.62, 0.55, 0.5 + (tint - 0.5) * _detail(0.25, fp))
        joint = _frac(x / 0.25) < 0.1 or _frac(y / 0.25) < 0.1
        d = _detail(0.05, fp)
        return _mix(r, g, b, 0.25, 0.24, 0.22, (d if joint else 0.0) * 0.7 + (1 - d) * 0.13)
    t = _fractal(noise, 0.8 * x, 0.8 * y + 50.0)
    return _mix(0.26, 0.44, 0.18, 0.44, 0.56, 0.28, t)


@njit(cache=True)
def shade(ox, oy, oz, dx, dy, dz, t, k, face, footprint_per_m, scene):
    """Colour (rgb in [0, 1]) of the hit (t, k, face) of the unit ray o + t d; the pixel's
    footprint on the surface is t * footprint_per_m (m)."""
    boxes, params, _, _, _, kinds, noise, meta = scene
    if k == SKY:
        h = math.sqrt(_clamp01(dz))
        return _mix(_HORIZON[0], _HORIZON[1], _HORIZON[2], _ZENITH[0], _ZENITH[1], _ZENITH[2], h)
    x, y, z = ox + t * dx, oy + t * dy, oz + t * dz
    fp = t * footprint_per_m
    nx, ny, nz = 0.0, 0.0, 1.0
    if k == GROUND:
        r, g, b = _ground(x, y, kinds, noise, meta[4], int(meta[5]), fp)
    else:
        p = params[k]
        box = boxes[k]
        if face == 5 or face == 4:
            r, g, b = _roof(p, box, x, y, noise, fp)
            nz = 1.0 if face == 5 else -1.0
        else:
            nz = 0.0
            if face == 0:
                u, length, nx = box[4] - y, box[4] - box[1], -1.0
            elif face == 1:
                u, length, nx = y - box[1], box[4] - box[1], 1.0
            elif face == 2:
                u, length, ny = x - box[0], box[3] - box[0], -1.0
            else:
                u, length, ny = box[3] - x, box[3] - box[0], 1.0
            r, g, b = _facade(p, u, z - box[2], length, box[5] - box[2], noise, fp)
    light = _AMBIENT + (1 - _AMBIENT) * max(0.0, nx * _LIGHT[0] + ny * _LIGHT[1] + nz * _LIGHT[2])
    haze = 1.0 - math.exp(-t / _HAZE_M)
    r, g, b = _mix(r * light, g * light, b * light, _HORIZON[0], _HORIZON[1], _HORIZON[2], haze)
    return _clamp01(r), _clamp01(g), _clamp01(b)


# --- kernels --------------------------------------------------------------------------------

@njit(cache=True)
def _camera_ray(rotation, fx, fy, cx, cy, px, py):
    """Unit world direction through image point (px, py) of a camera with world-to-camera
    rotation [3, 3]."""
    x, y = (px - cx) / fx, (py - cy) / fy
    dx = rotation[0, 0] * x + rotation[1, 0] * y + rotation[2, 0]
    dy = rotation[0, 1] * x + rotation[1, 1] * y + rotation[2, 1]
    dz = rotation[0, 2] * x + rotation[1, 2] * y + rotation[2, 2]
    norm = math.sqrt(dx * dx + dy * dy + dz * dz)   # >= 1: the camera-space z component is 1
    return dx / norm, dy / norm, dz / norm


@njit(cache=True)
def _pixel_sample(rotation, centre, fx, fy, cx, cy, px, py, per_m, scene):
    dx, dy, dz = _camera_ray(rotation, fx, fy, cx, cy, px, py)
    t, k, face = trace_ray(centre[0], centre[1], centre[2], dx, dy, dz, scene)
    r, g, b = shade(centre[0], centre[1], centre[2], dx, dy, dz, t, k, face, per_m, scene)
    return r, g, b, k * 8 + face


@njit(parallel=True, cache=True)
def render_kernel(rotation, centre, fx, fy, cx, cy, offsets, threshold, scene, colour, surface, out):
    """out [H, W, 3] uint8 <- each pixel's colour: one ray through its centre, and where a
    4-neighbour shows another surface or a colour more than ``threshold`` apart (an edge, a
    window frame), the mean of that ray and rays through (i + offsets[s, 0], j + offsets[s, 1]).
    colour [H, W, 3] float64 and surface [H, W] int64 are scratch."""
    height, width = out.shape[0], out.shape[1]
    per_m = 1.0 / max(fx, fy)
    for j in prange(height):
        for i in range(width):
            r, g, b, code = _pixel_sample(rotation, centre, fx, fy, cx, cy, i + 0.5, j + 0.5, per_m, scene)
            colour[j, i, 0], colour[j, i, 1], colour[j, i, 2] = r, g, b
            surface[j, i] = code
    for j in prange(height):
        for i in range(width):
            r, g, b = colour[j, i, 0], colour[j, i, 1], colour[j, i, 2]
            edge = False
            for n in range(4):
                jj = j + (1 if n == 0 else (-1 if n == 1 else 0))
                ii = i + (1 if n == 2 else (-1 if n == 3 else 0))
                if jj < 0 or jj >= height or ii < 0 or ii >= width:
                    continue
                if surface[jj, ii] != surface[j, i] or max(abs(colour[jj, ii, 0] - r), max(
                        abs(colour[jj, ii, 1] - g), abs(colour[jj, ii, 2] - b))) > threshold:
                    edge = True
                    break
            if edge:
                for s in range(offsets.shape[0]):
                    sr, sg, sb, _ = _pixel_sample(rotation, centre, fx, fy, cx, cy, i + offsets[s, 0],
                                                  j + offsets[s, 1], per_m, scene)
                    r += sr
                    g += sg
                    b += sb
                count = 1.0 + offsets.shape[0]
                r, g, b = r / count, g / count, b / count
            out[j, i, 0] = np.uint8(min(255.0, math.floor(r * 255.0 + 0.5)))
            out[j, i, 1] = np.uint8(min(255.0, math.floor(g * 255.0 + 0.5)))
            out[j, i, 2] = np.uint8(min(255.0, math.floor(b * 255.0 + 0.5)))


@njit(parallel=True, cache=True)
def trace_kernel(origins, dirs, footprint_per_m, scene, t_out, k_out, face_out, colour_out):
    """Trace rays origins, dirs [R, 3] (dirs unit) -> t [R], hit code [R], face [R], rgb [R, 3]."""
    for r in prange(origins.shape[0]):
        ox, oy, oz = origins[r, 0], origins[r, 1], origins[r, 2]
        dx, dy, dz = dirs[r, 0], dirs[r, 1], dirs[r, 2]
        t, k, face = trace_ray(ox, oy, oz, dx, dy, dz, scene)
        t_out[r], k_out[r], face_out[r] = t, k, face
        cr, cg, cb = shade(ox, oy, oz, dx, dy, dz, t, k, face, footprint_per_m[r], scene)
        colour_out[r, 0], colour_out[r, 1], colour_out[r, 2] = cr, cg, cb


@njit(cache=True)
def visible_from(px, py, pz, rotation, centre, fx, fy, cx, cy, width, height, scene):
    """Whether the surface point p lies in the camera's image and no surface hides it."""
    vx, vy, vz = px - centre[0], py - centre[1], pz - centre[2]
    zc = rotation[2, 0] * vx + rotation[2, 1] * vy + rotation[2, 2] * vz
    if zc <= 0.05:
        return False
    u = fx * (rotation[0, 0] * vx + rotation[0, 1] * vy + rotation[0, 2] * vz) / zc + cx
    v = fy * (rotation[1, 0] * vx + rotation[1, 1] * vy + rotation[1, 2] * vz) / zc + cy
    if u < 0.0 or v < 0.0 or u >= width or v >= height:
        return False
    dist = math.sqrt(vx * vx + vy * vy + vz * vz)   # >= zc > 0.05
    t, _, _ = trace_ray(centre[0], centre[1], centre[2], vx / dist, vy / dist, vz / dist, scene)
    # The ray reaches p's surface unless something nearer stops it; the tolerance absorbs the
    # rounding of two different rays meeting one plane.
    return t >= dist * (1.0 - 1e-6) - 1e-4


@njit(parallel=True, cache=True)
def witness_kernel(points, source, rotations, centres, intrinsics, sizes, wanted, window, scene, out):
    """out [P] <- how many cameras other than source[p] see points[p] (stopping at ``wanted``),
    trying cameras nearest in index first (neighbours along a walk see the same things) and
    none further than ``window`` in index. rotations [C, 3, 3], centres [C, 3], intrinsics
    [C, 4] (fx, fy, cx, cy), sizes [C, 2]."""
    cameras = rotations.shape[0]
    for p in prange(points.shape[0]):
        found = 0
        s = source[p]
        for step in range(1, 2 * min(cameras, window + 1)):
            offset = (step + 1) // 2 if step % 2 == 1 else -(step // 2)
            j = s + offset
            if j < 0 or j >= cameras:
                continue
            if visible_from(points[p, 0], points[p, 1], points[p, 2], rotations[j], centres[j],
                            intrinsics[j, 0], intrinsics[j, 1], intrinsics[j, 2], intrinsics[j, 3],
                            sizes[j, 0], sizes[j, 1], scene):
                found += 1
                if found >= wanted:
                    break
        out[p] = found
