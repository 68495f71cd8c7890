"""Rendering the simulated world (numpy + OpenCV): a wooden table of planks under uneven light, the
garment's layers with fabric texture, wrinkles, fold shading and a soft shadow, sensor noise and blur.

Everything static is computed once: the table texture per table seed (in the table plane), the lit,
noisy, blurred empty-table image per camera pose and scene. A render then only redoes the garment's
bounding box, which keeps a 1280x1024 frame fast.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from drivers.camera.model import CameraModel
from drivers.robot.table import TableConfig
from drivers.sim.config import Palette, RenderConfig, TableLookConfig
from drivers.sim.folding import Layer

_SUBPIXEL = 4          # fillPoly fractional bits
_SUPERSAMPLE = 4       # sub-samples per pixel side for polygon coverage
_BLUR_PAD = 8          # pixels around a redrawn region so blur and shadow match the cached frame


@dataclass(frozen=True)
class TableTexture:
    image: np.ndarray         # float32 BGR 0..255, rows along table x, columns along table y
    origin: np.ndarray        # table xy of texel (0, 0)
    resolution: float         # m per texel

    def texel_to_table(self) -> np.ndarray:
        """3x3 map of homogeneous texel (col, row, 1) to table (x, y, 1)."""
        r, (ox, oy) = self.resolution, self.origin
        return np.array([[0.0, r, ox], [r, 0.0, oy], [0.0, 0.0, 1.0]])


def _smooth_noise(rng: np.random.Generator, shape: tuple[int, int], cells: tuple[int, int]) -> np.ndarray:
    """Zero-mean, unit-ish smooth noise: a coarse random grid upscaled with cubic interpolation."""
    coarse = rng.standard_normal((max(cells[0], 2), max(cells[1], 2))).astype(np.float32)
    return cv2.resize(coarse, (shape[1], shape[0]), interpolation=cv2.INTER_CUBIC)


@dataclass(frozen=True)
class TableLook:
    """One physical table, drawn from `TableLookConfig`'s ranges by its seed."""

    wood_bgr: tuple[float, ...]
    plank_tint: float
    grain_contrast: float
    seam_darkness: float
    seam_width: float


@lru_cache(maxsize=4)
def draw_table_look(cfg: TableLookConfig) -> TableLook:
    rng = np.random.default_rng([cfg.seed, 0])
    low, high = cfg.wood_bgr
    # one brightness and a small hue change: laminates differ more in lightness than in colour
    level, hue = rng.random(), rng.uniform(-0.15, 0.15, 3)
    wood = tuple(lo + (hi - lo) * float(np.clip(level + change, 0.0, 1.0))
                 for lo, hi, change in zip(low, high, hue, strict=True))
    tint, contrast, darkness, seam = (float(rng.uniform(*r)) for r in
                                      (cfg.plank_tint, cfg.grain_contrast, cfg.seam_darkness, cfg.seam_width))
    return TableLook(wood, tint, contrast, darkness, seam)


@lru_cache(maxsize=2)
def table_texture(cfg: RenderConfig, table: TableConfig) -> TableTexture:
    """Planks running along the table's width (table y), with grain, butt joints, seams; floor around."""
    look = draw_table_look(cfg.table_look)
    rng = np.random.default_rng([cfg.table_look.seed, 1])
    res, margin = cfg.texture_resolution, cfg.floor_margin
    rows = int(np.ceil((table.size_x + 2 * margin) / res))
    cols = int(np.ceil((table.size_y + 2 * margin) / res))
    origin = np.array([-margin, -margin])
    img = np.empty((rows, cols, 3), np.float32)
    img[:] = np.array(cfg.floor_bgr, np.float32) * (1 + 0.05 * _smooth_noise(rng, (rows, cols), (8,
                                                                                                 10)))[...,
                                                                                                       None]
    r0, r1 = round(margin / res), round((margin + table.size_x) / res)
    c0, c1 = round(margin / res), round((margin + table.size_y) / res)
    th, tw = r1 - r0, c1 - c0
    wood = np.empty((th, tw), np.float32)
    # grain: streaks stretched along the plank, rings bent by slow noise
    streak = _smooth_noise(rng, (th, tw), (th // 3, max(tw // 300, 2)))
    # the grain bends slowly along the plank (few cells along it), so its lines stay long and straight-ish
    bend = _smooth_noise(rng, (th, tw), (th // 40, max(tw // 250, 2))) * 22.0
    rr = np.arange(th, dtype=np.float32)[:, None]
    rings = (np.sin((rr + bend) * (2 * np.pi / 38.0)) * 0.5
             + np.sin((rr * 0.37 + bend * 1.7) * (2 * np.pi / 11.0)) * 0.3)
    fine = cv2.GaussianBlur(rng.standard_normal((th, tw)).astype(np.float32), (0, 0), sigmaX=6.0, sigmaY=0.6)
    wood[:] = 1.0 + look.grain_contrast * (0.5 * streak + 0.6 * rings + 1.5 * fine)
    seam_px = max(round(look.seam_width / res), 1)
    edge = 0
    while edge < th:
        width = int(rng.uniform(*cfg.table_look.plank_width) / res)
        stop = min(edge + width, th)
        wood[edge:stop] *= 1.0 + look.plank_tint * float(rng.standard_normal())
        # butt joints: a plank is made of boards of random length
        pos = int(rng.uniform(0.1, 0.9) * tw)
        while pos < tw:
            wood[edge:stop, pos:pos + seam_px] *= 1.0 - look.seam_darkness
            wood[edge:stop, pos + seam_px: pos + 4 * seam_px] *= 1.0 + 0.3 * look.plank_tint
            pos += int(rng.uniform(0.6, 1.4) * tw)
        wood[edge:edge + seam_px] *= 1.0 - look.seam_darkness
        wood[edge + seam_px: edge + 3 * seam_px] *= 1.0 + 0.5 * look.plank_tint   # bevelled edge: light
        edge = stop
    tint = np.array(look.wood_bgr, np.float32)
    # warmer (less blue) in darker grain, as in real wood
    img[r0:r1, c0:c1] = wood[..., None] * tint * np.array([0.96, 1.0, 1.0], np.float32) ** (1 - wood[...,
                                                                                                     None])
    return TableTexture(image=img, origin=origin, resolution=res)


@dataclass(frozen=True)
class Appearance:
    """How one garment looks (from its scene seed)."""

    bgr: tuple[float, ...]            # blue, green, red 0..255
    texture: str
    table_like: bool
    wrinkled: bool
    seed: int


def choose_appearance(palette: tuple[Palette, ...], cfg: RenderConfig, wrinkled: bool,
                      rng: np.random.Generator) -> Appearance:
    table_like = bool(rng.random() < cfg.table_like_fraction)
    pal = palette[int(rng.integers(len(palette)))]
    if table_like:
        wood = np.array(draw_table_look(cfg.table_look).wood_bgr)
        base = wood * (1.0 + rng.uniform(-cfg.table_like_jitter, cfg.table_like_jitter, 3))
    else:
        base = np.array(pal.bgr) + rng.uniform(-pal.jitter, pal.jitter, 3)
    bgr = tuple(float(v) for v in np.clip(base, 5, 250))
    return Appearance(bgr=bgr, texture=pal.texture, table_like=table_like, wrinkled=wrinkled,
                      seed=int(rng.integers(2**31)))


class SceneRenderer:
    """Renders one scene (one garment's look and one lighting draw) from any camera pose."""

    def __init__(self, cfg: RenderConfig, table: TableConfig, appearance: Appearance, light_seed: int,
                 base_camera: CameraModel):
        self.cfg = cfg
        self.table = table
        self.appearance = appearance
        self.base_camera = base_camera
        w, h = base_camera.config.width, base_camera.config.height
        self.size = (w, h)
        rng = np.random.default_rng(light_seed)
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        diag = float(np.hypot(w, h))
        cx = w / 2 + rng.uniform(-1, 1) * cfg.bright_jitter * w
        cy = h / 2 + rng.uniform(-1, 1) * cfg.bright_jitter * h
        r2 = ((xx - cx) ** 2 + (yy - cy) ** 2) / (cfg.bright_sigma * diag) ** 2
        rn2 = ((xx - w / 2) ** 2 + (yy - h / 2) ** 2) / (diag / 2) ** 2
        exposure = 1.0 + rng.uniform(-1, 1) * cfg.exposure_jitter
        vignette = rng.uniform(*cfg.table_look.vignette)
        # a window or a lamp off to one side: brightness falls linearly across the image
        ramp_angle, ramp = rng.uniform(0, 2 * np.pi), rng.uniform(*cfg.table_look.light_gradient)
        across = ((xx - w / 2) * np.cos(ramp_angle) + (yy - h / 2) * np.sin(ramp_angle)) / diag
        self.illum = (cfg.light_gain * exposure * (1.0 + cfg.bright_gain * np.exp(-0.5 * r2))
                      * (1.0 - vignette * rn2 ** 1.5) * (1.0 - ramp * (0.5 + across))).astype(np.float32)
        self.noise = (rng.standard_normal((h, w, 3)) * cfg.noise_sigma).astype(np.float32)
        self.fabric = self._fabric_field(np.random.default_rng(appearance.seed))
        self._pose_key: bytes | None = None
        self._table_img: np.ndarray | None = None
        self._base: np.ndarray | None = None

    # --- static parts ------------------------------------------------------------------------
    def _fabric_field(self, rng: np.random.Generator) -> np.ndarray:
        cfg, (w, h) = self.cfg, self.size
        a = self.appearance
        field = 1.0 + cfg.mottle_strength * _smooth_noise(rng, (h, w), (h // 48, w // 48))
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        fine = rng.standard_normal((h, w)).astype(np.float32)
        if a.texture == "twill":
            weave = np.sin((xx + yy) * (2 * np.pi / 3.3)) * 0.6 + 0.6 * cv2.GaussianBlur(fine, (0, 0), 0.7)
            field += cfg.texture_strength * weave * 1.3
            # faded denim: lighter streaks along the legs
            field += 0.5 * cfg.mottle_strength * _smooth_noise(rng, (h, w), (h // 12, w // 80))
        elif a.texture == "terry":
            field += cfg.texture_strength * 2.0 * cv2.GaussianBlur(fine, (0, 0), 1.0) * 1.6
        elif a.texture == "pique":
            grid = np.sin(xx * (2 * np.pi / 2.7)) * np.sin(yy * (2 * np.pi / 2.7))
            field += cfg.texture_strength * (0.5 * grid + 0.8 * cv2.GaussianBlur(fine, (0, 0), 0.6))
        else:  # knit: ribs
            ribs = np.sin(xx * (2 * np.pi / 4.0) + 0.3 * np.sin(yy * 0.05))
            field += cfg.texture_strength * (0.7 * ribs + 0.6 * cv2.GaussianBlur(fine, (0, 0), 0.6))
        lo, hi = cfg.wrinkle_count
        n = int(rng.integers(lo, hi + 1))
        strength = cfg.wrinkle_strength * (1.0 if a.wrinkled else 0.35)
        sw, sh = w // 4, h // 4
        ridges = np.zeros((sh, sw), np.float32)
        for _ in range(n):
            p = rng.uniform([0, 0], [sw, sh])
            ang = rng.uniform(0, np.pi)
            ln = rng.uniform(0.05, 0.2) * sw
            q = p + ln * np.array([np.cos(ang), np.sin(ang)])
            cv2.line(ridges, tuple(int(v) for v in p), tuple(int(v) for v in q), float(rng.uniform(0.5, 1.0)),
                     thickness=int(rng.integers(5, 10)), lineType=cv2.LINE_AA)
        heights = cv2.GaussianBlur(ridges, (0, 0), 5.0)
        # lit from one side: the gradient of the ridge height gives light and dark flanks
        shade = cv2.Sobel(heights, cv2.CV_32F, 1, 0, ksize=3) + 0.5 * cv2.Sobel(heights, cv2.CV_32F, 0, 1,
                                                                                ksize=3)
        shade = cv2.resize(shade, (w, h), interpolation=cv2.INTER_LINEAR)
        field += strength * shade * 4.0
        return field.astype(np.float32)

    def _prepare(self, camera: CameraModel) -> None:
        key = camera.pose_in_world.tobytes()
        if key == self._pose_key:
            return
        tex = table_texture(self.cfg, self.table)
        h_img = camera.table_to_image @ tex.texel_to_table()
        table_img = cv2.warpPerspective(tex.image, h_img, self.size, flags=cv2.INTER_LINEAR,
                                        borderMode=cv2.BORDER_CONSTANT, borderValue=self.cfg.floor_bgr)
        self._table_img = table_img
        self._base = self._finish(table_img, self.illum, self.noise)
        self._pose_key = key

    def _finish(self, linear: np.ndarray, illum: np.ndarray, noise: np.ndarray) -> np.ndarray:
        img = linear * illum[..., None] + noise
        if self.cfg.blur_sigma > 0:
            img = cv2.GaussianBlur(img, (0, 0), self.cfg.blur_sigma)
        return np.clip(img + 0.5, 0, 255).astype(np.uint8)

    # --- per frame ---------------------------------------------------------------------------
    def render(self, layers: list[Layer], camera: CameraModel | None = None) -> np.ndarray:
        camera = camera or self.base_camera
        self._prepare(camera)
        assert self._base is not None and self._table_img is not None
        out = self._base.copy()
        if not layers:
            return out
        w, h = self.size
        polys = [camera.table_to_pixel(layer.polygon) for layer in layers]
        allpx = np.vstack(polys)
        pad = _BLUR_PAD + self.cfg.shadow_blur + int(max(abs(v) for v in self.cfg.shadow_offset))
        x0 = int(max(np.floor(allpx[:, 0].min()) - pad, 0))
        y0 = int(max(np.floor(allpx[:, 1].min()) - pad, 0))
        x1 = int(min(np.ceil(allpx[:, 0].max()) + pad, w))
        y1 = int(min(np.ceil(allpx[:, 1].max()) + pad, h))
        if x1 <= x0 or y1 <= y0:
            return out
        rw, rh = x1 - x0, y1 - y0
        region = self._table_img[y0:y1, x0:x1].copy()
        masks = [self._mask(p, x0, y0, rw, rh) for p in polys]
        cfg = self.cfg
        union = np.maximum.reduce(masks)
        dx, dy = cfg.shadow_offset
        shift = np.array([[1, 0, dx], [0, 1, dy]], np.float32)
        shadow = cv2.warpAffine(union, shift, (rw, rh))
        k = cfg.shadow_blur | 1
        shadow = cv2.GaussianBlur(shadow, (k, k), 0)
        region *= (1.0 - cfg.shadow_strength * shadow)[..., None]
        colour = np.array(self.appearance.bgr, np.float32)
        fabric = self.fabric[y0:y1, x0:x1]
        ew = cfg.fold_edge_width | 1
        for i, (layer, m) in enumerate(zip(layers, masks, strict=True)):
            if i > 0:
                # an upper layer casts a thin shadow on what lies below and its folded edge is darker
                soft = cv2.GaussianBlur(m, (ew * 2 + 1, ew * 2 + 1), 0)
                region *= (1.0 - cfg.fold_edge_darkening * 0.6 * soft * (1.0 - m))[..., None]
                edge_shade = 1.0 - cfg.fold_edge_darkening * (1.0 - cv2.GaussianBlur(m, (ew, ew), 0))
            else:
                edge_shade = 1.0 - 0.3 * cfg.fold_edge_darkening * (1.0 - cv2.GaussianBlur(m, (ew, ew), 0))
            shade = fabric * edge_shade * (cfg.backside_shade if layer.flipped else 1.0)
            layer_img = colour[None, None, :] * shade[..., None]
            region += (layer_img - region) * m[..., None]
        # redo lighting, noise and blur on the region; keep only its interior
        fin = self._finish(region, self.illum[y0:y1, x0:x1], self.noise[y0:y1, x0:x1])
        ix0 = 0 if x0 == 0 else _BLUR_PAD
        iy0 = 0 if y0 == 0 else _BLUR_PAD
        ix1 = rw if x1 == w else rw - _BLUR_PAD
        iy1 = rh if y1 == h else rh - _BLUR_PAD
        out[y0 + iy0:y0 + iy1, x0 + ix0:x0 + ix1] = fin[iy0:iy1, ix0:ix1]
        return out

    @staticmethod
    def _mask(poly_px: np.ndarray, x0: int, y0: int, rw: int, rh: int) -> np.ndarray:
        """Pixel coverage (0..1) of a polygon, by 4x4 supersampling: unbiased to a fraction of a pixel
        (OpenCV's anti-aliased fill grows shapes by about half a pixel)."""
        m = np.zeros((rh, rw), np.float32)
        local = poly_px - [x0, y0]
        bx0 = int(max(np.floor(local[:, 0].min()) - 1, 0))
        by0 = int(max(np.floor(local[:, 1].min()) - 1, 0))
        bx1 = int(min(np.ceil(local[:, 0].max()) + 2, rw))
        by1 = int(min(np.ceil(local[:, 1].max()) + 2, rh))
        if bx1 <= bx0 or by1 <= by0:
            return m
        ss = _SUPERSAMPLE
        big = np.zeros(((by1 - by0) * ss, (bx1 - bx0) * ss), np.uint8)
        # pixel i spans [i - 0.5, i + 0.5]; its sub-sample k has its centre at i - 0.5 + (k + 0.5) / ss
        sub = (local - [bx0, by0] + 0.5) * ss - 0.5
        pts = np.round(sub * (1 << _SUBPIXEL)).astype(np.int32).reshape(-1, 1, 2)
        cv2.fillPoly(big, [pts], 255, lineType=cv2.LINE_8, shift=_SUBPIXEL)
        small = cv2.resize(big, (bx1 - bx0, by1 - by0), interpolation=cv2.INTER_AREA)
        m[by0:by1, bx0:bx1] = small.astype(np.float32) * (1.0 / 255.0)
        return m


def encode_png(image: np.ndarray, compression: int) -> bytes:
    """Lossless, deterministic PNG bytes of a BGR image (no timestamps or metadata)."""
    ok, buf = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, compression])
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()
