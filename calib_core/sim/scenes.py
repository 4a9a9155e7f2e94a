"""Frames of a dot plate as a camera at a machine sees it, rendered with exact centres by
supersampling (independently of calib_core.sim.render, whose model the detector shares):
24 dark dots of 9 px radius on a grey plate, blur 1 px, noise 2 grey levels, in the scenes
a detector meets at a machine (issue 55): the plate on a dark or a light table, in a round
field of view, under uneven light, with a specular hot spot, defocused, a cable across
it, plates smaller than the frame at several positions. Used by the tests and
``machine_alignment.bench.mark_scenes``."""
from __future__ import annotations

import cv2
import numpy as np

PLATE, DOT = 150.0, 40.0        # grey levels
RADIUS, BLUR, NOISE = 9.0, 1.0, 2.0
SUPERSAMPLING = 16          # 8 left a coverage step of 1/64 (0.9 grey levels on the edge)
HOT_SPOT = 90.0             # grey levels at the highlight's peak


def disk_coverage(shape, centres, radius):
    """Each pixel's share inside any disk (centres (k, 2) px, pixel centres at integers),
    by SUPERSAMPLING x SUPERSAMPLING points a pixel."""
    cover = np.zeros(shape)
    offsets = (np.arange(SUPERSAMPLING) + 0.5) / SUPERSAMPLING - 0.5
    for cx, cy in centres:
        x0, y0 = int(cx - radius - 2), int(cy - radius - 2)
        ys, xs = np.mgrid[y0:int(cy + radius + 3), x0:int(cx + radius + 3)]
        inside = sum(((xs + ox - cx) ** 2 + (ys + oy - cy) ** 2 <= radius ** 2)
                     for oy in offsets for ox in offsets) / SUPERSAMPLING ** 2
        cover[y0:y0 + ys.shape[0], x0:x0 + ys.shape[1]] = np.maximum(
            cover[y0:y0 + ys.shape[0], x0:x0 + ys.shape[1]], inside)
    return cover


def uneven_light(u, width: int):
    """The 'uneven' scene's light at column ``u`` (px): 45 % less across the frame."""
    return 1.0 - 0.45 * np.asarray(u, float) / width


def shadow_light(u, edge: float, shade: float = 0.3, soft: float = 2.0):
    """A shadow's light at column ``u`` (px): ``shade`` of it beyond the column ``edge``
    (px), which is ``soft`` px wide (a logistic step)."""
    return shade + (1 - shade) * 0.5 * (1 - np.tanh((np.asarray(u, float) - edge) / (2 * soft)))


def dot_plate(kind: str, seed: int, shape=(480, 640), columns: int = 6, rows: int = 4,
              pitch: float = 45.0, centre=None, blur: float = BLUR):
    """A frame (uint8) of ``kind`` and its dots' true centres (k, 2) px.

    kind: 'plain' (the plate fills the view), 'dark_table', 'light_table', 'round_view'
    (white outside a circle), 'uneven' (45 % less light across the plate), 'hot_spot' (a
    specular highlight of +90 grey levels, 25 px wide, over the edge of the ninth dot, or
    of the only one), 'cable' (a dark cable across the plate between two rows),
    'small_plate' (a plate of ``columns`` x ``rows`` dots at ``centre`` on a dark table),
    'shadow' (a hard shadow, 30 % of the light, over the plate beyond a vertical edge a
    pitch right of the plate's centre, 2 px soft)."""
    rng = np.random.default_rng(seed)
    height, width = shape
    cx, cy = (np.array(centre, float) if centre is not None
              else np.array([width / 2, height / 2])) + rng.uniform(-5, 5, 2)
    centres = np.array([[cx + (i - (columns - 1) / 2) * pitch + rng.uniform(-0.5, 0.5),
                         cy + (j - (rows - 1) / 2) * pitch + rng.uniform(-0.5, 0.5)]
                        for j in range(rows) for i in range(columns)])
    ys, xs = np.mgrid[0:height, 0:width].astype(float)
    on_plate = ((np.abs(xs - cx) < (columns / 2 + 0.5) * pitch)
                & (np.abs(ys - cy) < (rows / 2 + 0.5) * pitch))
    light = np.ones(shape)
    if kind in ('dark_table', 'small_plate'):
        surround = np.where(on_plate, PLATE, 20.0)
    elif kind == 'light_table':
        surround = np.where(on_plate, PLATE, 240.0)
    elif kind == 'round_view':
        surround = np.where((xs - width / 2) ** 2 + (ys - height / 2) ** 2
                            < (0.41 * width) ** 2, PLATE, 250.0)
    else:
        surround = np.full(shape, PLATE)
    if kind == 'uneven':
        light = uneven_light(xs, width)
    if kind == 'shadow':
        light = shadow_light(xs, cx + pitch)
    cover = disk_coverage(shape, centres, RADIUS)
    frame = (surround * (1 - cover) + DOT * cover) * light
    if kind == 'hot_spot':
        hu, hv = centres[min(8, len(centres) - 1)] + [14.0, 6.0]
        frame = frame + HOT_SPOT * np.exp(-((xs - hu) ** 2 + (ys - hv) ** 2) / (2 * 12.5 ** 2))
    if kind == 'cable':
        frame = np.where(np.abs(ys - cy - 0.03 * (xs - cx)) < 5, 25.0, frame)
    frame = cv2.GaussianBlur(frame, (0, 0), blur) + rng.normal(0, NOISE, shape)
    return np.clip(np.round(frame), 0, 255).astype(np.uint8), centres
