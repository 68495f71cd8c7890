"""Garment segmentation (paper Sec. III-A): table-GMM trimap (Eq. 1) -> GrabCut -> outer border.

Steps: downsample to `work_size` (320x256); divide each pixel by the table's learned brightness
field; label by the table GMM's log-likelihood against P_F / P_B (Eq. 1); initialise GrabCut's
mask with the trimap (sure table fixed; foreground pixels start as probable garment, since 3 % of
table pixels are foreground by construction, unknown ones as probable table) inside the box of
the likely garment, and run at most 3 iterations; keep the largest connected region. The coarse
border is then refined at full resolution in a narrow band by a per-pixel likelihood ratio
between the table GMM and a Gaussian of the garment's colour, and the outer border of the
full-resolution mask is traced (OpenCV's border following).

Around the paper's method (each a config field of `segmentation:`):
* GrabCut's colour GMMs are initialised here by the binary-split palette algorithm with
  `grabcut_components` (3, the paper's number) and GrabCut runs in GC_EVAL mode. OpenCV's own
  initialisation always makes 5 components by k-means, which took most of GrabCut's time; a
  component of weight 0 is never given a pixel by OpenCV, so GrabCut keeps exactly 3.
* Optionally GrabCut sees the colours divided by the light field (`grabcut_flat_light`, off by
  default: it helps pale garments on the held-out set but made the in-cell verification of a
  folded shirt less reliable).
* If GrabCut's largest region keeps less than `grabcut_keep_fraction` of the solid core of the
  sure-garment pixels (surviving an opening of `sure_fg_radius_px`), GrabCut has swapped its
  colour models on a garment close to the table's colour and dropped most of it: it is run
  again with that core fixed as garment. Small sure-table blobs inside
  the garment (shadows the colour of wood) are only probable table (`min_table_blob_fraction`).
* Thin slits closed at work size (a sleeve against the body, the crotch) are opened at full
  resolution where table-coloured pixels connect to the table outside (`open_slits`).
* Spurs and notches of a few pixels are removed by an opening and closing (`spur_radius_px`):
  they would draw polygon vertices with absurd angles and wreck the matching.
* Unknown pixels of the table's colour at a brightness the light allows, connected to the table
  around the garment through such pixels, are fixed as table (`unknown_table_hue_fixed`): a
  darker plank beside the garment, left free, was taken whole by GrabCut's garment model.
* GrabCut stops before its 3rd iteration when an iteration changes fewer than
  `grabcut_converged_fraction` of its labels (border pixels, which the refinement labels again).
* Speed: likelihoods in float32 with element-wise products (no BLAS threads), colours read only
  at the band pixels, a square band (separable morphology), the band's masks as OpenCV 0/255
  images.

Uneven light, in three layers: (1) both the trimap and the refinement see colours divided by
the table's learned brightness field (see `table_model`), so a bright centre and dark corners keep
table pixels near the GMM's modes; (2) per image, a smooth change of log brightness (exposure, a
bright spot that moved: a robust quadratic plus a coarse residual grid) is fitted to the
table-coloured pixels and divided out too (`light_correction`); (3) the trimap's unknown band and
GrabCut absorb what is left (glare), since GrabCut re-estimates its colour models from the image.

Robustness to garments close to the table's colour (each a config field of `segmentation:`):
* The light correction must not explain a garment as the table under another light (it would
  divide the garment into the table's colour: a dark wood-hued garment was fitted as a shadow,
  the table around it then looked like garment). Table-coloured means: the colour at its best
  brightness is typical of a GMM component (`ray_mahalanobis2` within `light_mahalanobis`; the
  table's components are thin across the brightness direction, so this separates wood-coloured
  cloth far better than a chromaticity distance), the brightness is within a bounded change of
  the learned light (`light_max_log_change`, which also bounds the field).
* Clipped pixels (glare; `saturation_level`) have lost their colour and are never sure garment.
  They start GrabCut as probable table unless the unclipped pixels around them are mostly sure
  garment that is not of the table's colour and not brighter than the light model allows
  (`glare_context_px`, `glare_max_brightness`): the clipped highlights of a pale garment on the
  bright centre of the table belong to the garment (before, its colour models swapped and it
  lost whole legs), while glare on the table lies among table pixels, whose colour next to the
  glare is too bright (or distorted by clipped full-resolution pixels in the average) to vote.
  The refinement keeps the coarse label of clipped pixels.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from .config import SegmentationConfig
from .errors import GarmentTouchesBorder, NoGarmentFound
from .table_model import (
    TableModel,
    binary_split_init,
    check_image,
    covariance,
    gain_field,
    gaussian_log_likelihood,
    mahalanobis2,
    normalise,
    ray_mahalanobis2,
)


@dataclass(frozen=True)
class Segmentation:
    contour: NDArray     # (P, 2) int outer border, full-resolution pixels
    mask: NDArray        # (rows, cols) bool at full resolution (region of interest filled)
    trimap: NDArray      # (h, w) uint8 at work size: 0 bg, 1 unknown, 2 fg


def table_log_likelihood(img: NDArray, model: TableModel, correction: NDArray | None = None) -> NDArray:
    feats = normalise(img, model.gain)
    if correction is not None:
        feats = feats / np.exp(correction)[..., None]
    feats = feats.reshape(-1, 3).astype(float)
    ll = gaussian_log_likelihood(feats, model.weights, model.means, model.covariances)
    return ll.reshape(img.shape[:2])


def _clipped(img: NDArray, cfg: SegmentationConfig, model: TableModel,
             light: NDArray | None = None) -> NDArray:
    """Glare on the table: clipped channels have lost the colour, so the likelihood cannot judge.

    Two (not all) channels clipped with a hue still near the table's, or one channel clipped
    with the other two typical of the table (Mahalanobis distance of the 2-D marginal of a GMM
    component, after the light normalisation `light`, within `glare_mahalanobis`). A white
    garment clips all three and is left to the likelihood and GrabCut.
    """
    shape = img.shape[:2]
    px = img.reshape(-1, 3)
    lt = None if light is None else np.asarray(light).reshape(-1)
    return _clipped_px(px, cfg, model, lt).reshape(shape)


def _clipped_px(px: NDArray, cfg: SegmentationConfig, model: TableModel,
                light: NDArray | None = None) -> NDArray:
    """`_clipped` for (n, 3) uint8 pixels with their (n,) light (or None)."""
    sat = cfg.saturation_level
    # per-channel comparisons: numpy reduces a length-3 last axis slowly
    n = ((px[:, 0] >= sat).view(np.uint8) + (px[:, 1] >= sat).view(np.uint8)
         + (px[:, 2] >= sat).view(np.uint8))
    out = np.zeros(n.shape, bool)
    if not n.any():
        return out
    two = n == 2
    if two.any():
        p2 = px[two].astype(np.float32)
        chroma = p2 / (p2.sum(axis=1, keepdims=True) + 1e-6)
        mchroma = (model.means / model.means.sum(axis=1, keepdims=True)).astype(np.float32)
        dist = np.min(np.linalg.norm(chroma[:, None, :] - mchroma[None], axis=2), axis=1)
        out[two] = dist < cfg.glare_chroma_tolerance
    one = n == 1
    if one.any():
        p1 = px[one].astype(np.float64)
        if light is not None:
            p1 = p1 / light[one][:, None]
        which = np.argmax(px[one] >= cfg.saturation_level, axis=1)
        ok = np.zeros(len(p1), bool)
        for ch in range(3):
            sel = which == ch
            if not sel.any():
                continue
            keep = [c for c in range(3) if c != ch]
            for k in range(len(model.weights)):
                mu = model.means[k, keep]
                cov = model.covariances[k][np.ix_(keep, keep)]
                d = p1[sel][:, keep] - mu
                m2 = np.einsum("ij,jk,ik->i", d, np.linalg.inv(cov), d)
                ok[np.flatnonzero(sel)[m2 < cfg.glare_mahalanobis ** 2]] = True
        out[one] = ok
    return out


def _poly_terms(u: NDArray, v: NDArray) -> NDArray:
    return np.stack([np.ones_like(u), u, v, u * u, u * v, v * v], axis=-1)


def light_correction(small: NDArray, model: TableModel, cfg: SegmentationConfig) -> NDArray:
    """This image's smooth log-brightness change against the learned table light (exposure, a
    moved or larger bright spot), as an (h, w) field at work size.

    Fitted to table-coloured pixels only (on every `light_sample_stride`-th pixel), which must
    not include a garment, or the correction would divide it into the table's brightness:
    a pixel is table-coloured when its colour, at the best brightness, is typical of a GMM
    component (`ray_mahalanobis2` within `light_mahalanobis`; light scales colours, so this
    ignores brightness), its brightness is within `light_max_log_change` of the learned light
    (a dark garment of the wood's hue is not wood in a shadow), and no channel is clipped.
    First a quadratic surface, fitted robustly (outliers dropped); then the mean residual of
    its inliers per cell of a coarse grid (cells with too few of them get none), smoothed,
    captures a bright spot a quadratic cannot. The field is bounded by `light_max_log_change`.
    """
    h, w = small.shape[:2]
    st = cfg.light_sample_stride
    sub = small[st // 2::st, st // 2::st]
    sh, sw = sub.shape[:2]
    light = gain_field(model.gain, (h, w))[st // 2::st, st // 2::st]
    feats = (sub.astype(np.float32) / light[..., None]).reshape(-1, 3)
    m2, _ = ray_mahalanobis2(feats, model.weights, model.means, model.covariances)
    table_lum = float(model.weights @ model.means.mean(axis=1))
    lum = feats.mean(axis=1)
    target = np.log(np.maximum(lum, 1.0) / table_lum).astype(float)
    bound = cfg.light_max_log_change
    unclipped = (sub < cfg.saturation_level).all(axis=2).ravel()
    ok = (m2 < cfg.light_mahalanobis ** 2) & (lum > 1.0) & unclipped & (np.abs(target) < bound)
    if ok.sum() < cfg.light_min_fraction * sh * sw:
        return np.zeros((h, w), np.float32)
    yy, xx = np.divmod(np.arange(sh * sw), sw)
    A = _poly_terms((xx * st + st // 2 + 0.5) / w, (yy * st + st // 2 + 0.5) / h)
    keep = ok
    coeffs = np.zeros(6)
    for _ in range(3):
        # normal equations by einsum (no BLAS threads; 6 unknowns, well conditioned on [0, 1]^2)
        Ak = A[keep]
        coeffs = np.linalg.solve(np.einsum("ij,ik->jk", Ak, Ak) + 1e-9 * np.eye(6),
                                 np.einsum("ij,i->j", Ak, target[keep]))
        resid = target - np.einsum("ij,j->i", A, coeffs)
        mad = float(np.median(np.abs(resid[keep]))) + 1e-6
        keep = ok & (np.abs(resid) < 3.0 * 1.4826 * mad)
    rows, cols = cfg.light_grid
    resid = (target - np.einsum("ij,j->i", A, coeffs)).reshape(sh, sw)
    okg = keep.reshape(sh, sw)
    # per grid cell: the mean residual of the quadratic's inliers (sums over cell blocks)
    ry = np.arange(rows) * sh // rows
    rx = np.arange(cols) * sw // cols
    sums = np.add.reduceat(np.add.reduceat(np.where(okg, resid, 0.0), ry, axis=0), rx, axis=1)
    counts = np.add.reduceat(np.add.reduceat(okg.astype(float), ry, axis=0), rx, axis=1)
    sizes = np.outer(np.diff(np.append(ry, sh)), np.diff(np.append(rx, sw)))
    grid = np.where(counts >= cfg.light_min_fraction * sizes, sums / np.maximum(counts, 1.0), 0.0)
    grid = cv2.GaussianBlur(grid.astype(np.float32), (3, 3), 0)
    # the quadratic, separable: row terms + column terms + the cross term
    u = ((np.arange(w, dtype=np.float32) + 0.5) / w)[None, :]
    v = ((np.arange(h, dtype=np.float32) + 0.5) / h)[:, None]
    c = coeffs.astype(np.float32)
    field = (c[0] + c[1] * u + c[3] * u * u) + (c[2] * v + c[5] * v * v) + c[4] * (v * u)
    field = field + cv2.resize(grid, (w, h), interpolation=cv2.INTER_LINEAR)
    return np.clip(field, -bound, bound).astype(np.float32)


def _borrow_labels(tri: NDArray, clipped: NDArray, table_hue: NDArray, brighter: NDArray,
                   sigma: float) -> NDArray:
    """Clipped pixels that start GrabCut as probable garment: those among garment pixels.

    A clipped pixel has lost its colour, so its own likelihood says nothing; glare on the table
    lies among table pixels, the clipped highlights of a pale garment among garment pixels. A
    clipped pixel is probable garment when the unclipped pixels around it that are surely
    garment outweigh those that may be table, by Gaussian weights (`sigma`, work pixels).
    Surely garment: sure foreground, not of the table's colour at any brightness (`table_hue`)
    and not brighter than the light model allows (`brighter`: next to glare the light is
    stronger than modelled and clipping in the full-resolution pixels distorts the hue of
    their average); pixels next to clipped ones do not vote. Without votes: probable table.
    """
    known = cv2.dilate(clipped.view(np.uint8), np.ones((3, 3), np.uint8)) == 0
    garment_votes = (tri == 2) & ~table_hue & ~brighter & known
    table_votes = ((tri == 0) | table_hue) & known
    garment = cv2.GaussianBlur(garment_votes.astype(np.float32), (0, 0), sigma)
    table = cv2.GaussianBlur(table_votes.astype(np.float32), (0, 0), sigma)
    return clipped & (garment > table)


def trimap(ll: NDArray, model: TableModel) -> NDArray:
    """Eq. 1: 2 = foreground (p < P_F), 0 = background (p > P_B), 1 = unknown."""
    t = np.ones(ll.shape, np.uint8)
    t[ll < model.threshold_fg] = 2
    t[ll > model.threshold_bg] = 0
    return t


def _gmm_param(px: NDArray, cfg: SegmentationConfig) -> NDArray:
    """One GrabCut colour model (OpenCV's packed 1x65 layout for 5 components: weights, means,
    covariances) initialised by the binary-split palette algorithm with `grabcut_components`
    components; the others get weight 0, which OpenCV never assigns a pixel to, so GrabCut
    re-estimates exactly that many components in every iteration (the paper's 3)."""
    k_max = 5
    out = np.zeros((1, 13 * k_max), np.float64)
    x = px.astype(np.float64)
    if len(x) < 2:
        x = np.vstack([x, np.full((2, 3), 128.0)])[:2] if len(x) else np.full((2, 3), 128.0)
    labels = binary_split_init(x, min(cfg.grabcut_components, k_max))
    eye = np.eye(3) * cfg.grabcut_var_floor
    for c in range(min(cfg.grabcut_components, k_max)):
        pts = x[labels == c]
        if len(pts) < 2:
            continue
        out[0, c] = len(pts) / len(x)
        out[0, k_max + 3 * c:k_max + 3 * c + 3] = pts.mean(axis=0)
        out[0, 4 * k_max + 9 * c:4 * k_max + 9 * c + 9] = (covariance(pts) + eye).ravel()
    return out


def _grabcut_models(img: NDArray, gc: NDArray, cfg: SegmentationConfig) -> tuple[NDArray, NDArray]:
    """Background and foreground GMMs from the trimap-initialised mask (sampled pixels).

    Replaces OpenCV's own initialisation (k-means with 5 components, most of GrabCut's time at
    this size); GrabCut is then run in GC_EVAL mode, its usual iterations from these models.
    """
    st = cfg.grabcut_sample_stride
    gs, ims = gc[::st, ::st], img[::st, ::st]
    fg = (gs == cv2.GC_FGD) | (gs == cv2.GC_PR_FGD)
    return _gmm_param(ims[~fg], cfg), _gmm_param(ims[fg], cfg)


def _grabcut(img: NDArray, mask: NDArray, bgd: NDArray, fgd: NDArray, cfg: SegmentationConfig) -> None:
    """GrabCut (GC_EVAL from the given colour models) for at most `grabcut_iterations`, one at a time
    (the same result as one call), stopping once an iteration changes fewer than
    `grabcut_converged_fraction` of the labels: those are border pixels, which the full-resolution
    refinement labels again anyway."""
    for _ in range(cfg.grabcut_iterations):
        before = mask.copy()
        cv2.grabCut(img, mask, None, bgd, fgd, 1, cv2.GC_EVAL)
        if np.count_nonzero(before != mask) < cfg.grabcut_converged_fraction * mask.size:
            return


def _reaching_border(mask: NDArray) -> NDArray:
    """The pixels of a uint8 mask 4-connected within it to the array's border (bool)."""
    n, lab = cv2.connectedComponents(mask, connectivity=4)
    edge = np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]]))
    reaches = np.zeros(n, bool)
    reaches[edge[edge > 0]] = True
    return reaches[lab]


def _largest(mask: NDArray) -> NDArray:
    """The largest 8-connected region of a uint8 mask (bool; all False if empty)."""
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n <= 1:
        return np.zeros(mask.shape, bool)
    return labels == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))


def segment(image: NDArray, model: TableModel, cfg: SegmentationConfig) -> Segmentation:
    """The garment's outer border in full-resolution pixels; raises a `PerceptionError` subclass."""
    img = check_image(image)
    rows, cols = img.shape[:2]
    w, h = cfg.work_size
    small = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
    corr = light_correction(small, model, cfg) if cfg.adapt_light else None
    ll = table_log_likelihood(small, model, corr)
    tri = trimap(ll, model)
    # clipped pixels (glare) have lost their colour: never sure garment; probably table unless
    # among garment (`_borrow_labels`)
    light_small = gain_field(model.gain, (h, w))
    if corr is not None:
        light_small = light_small * np.exp(corr)
    saturated = _clipped(small, cfg, model, light_small)
    tri[saturated & (tri == 2)] = 1
    if not (tri == 2).any():
        raise NoGarmentFound("no pixel is unlike the table: no garment in the image")
    # Foreground labels are "probable": by construction 3 % of table pixels fall below P_F, and
    # GrabCut must be free to relabel them; only sure table pixels are fixed.
    likely = (tri == 2) & ~saturated
    if saturated.any():
        # the colour test only where it can change a vote (not sure table, unclipped, within
        # reach of a clipped pixel), for speed
        reach = 2 * int(np.ceil(3 * cfg.glare_context_px)) + 1
        near = cv2.dilate(saturated.view(np.uint8), np.ones((reach, reach), np.uint8)) > 0
        at = (tri != 0) & near & ~saturated
        feats = small[at].astype(np.float32) / light_small[at][:, None]
        m2, scale = ray_mahalanobis2(feats, model.weights, model.means, model.covariances)
        table_hue = np.zeros((h, w), bool)
        brighter = np.zeros((h, w), bool)
        table_hue[at] = m2 < cfg.light_mahalanobis ** 2
        brighter[at] = scale > cfg.glare_max_brightness
        likely |= _borrow_labels(tri, saturated, table_hue, brighter, cfg.glare_context_px)
    gc = np.where(tri == 0, cv2.GC_BGD, np.where(likely, cv2.GC_PR_FGD, cv2.GC_PR_BGD)).astype(np.uint8)
    if cfg.unknown_table_hue_fixed:
        # Unknown pixels of the table's colour, at a brightness the light allows, that reach the
        # table around the garment through such pixels (a darker plank beside the garment) are
        # table: left free, GrabCut's garment model can take a whole plank. Reaching out matters:
        # a wood-hued garment has pixels like these inside, enclosed by garment.
        at = (tri == 1) & ~saturated
        feats = small[at].astype(np.float32) / light_small[at][:, None]
        m2, scale = ray_mahalanobis2(feats, model.weights, model.means, model.covariances)
        wood = np.zeros((h, w), np.uint8)
        wood[at] = (m2 < cfg.light_mahalanobis ** 2) & (np.abs(np.log(np.maximum(scale, 1e-6)))
                                                         < cfg.light_max_log_change)
        # an opening cuts one-pixel chains (wood grain, noise) that would lead into a garment
        wood = cv2.morphologyEx(wood, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
        gc[(wood > 0) & _reaching_border(wood | (tri == 0).view(np.uint8))] = cv2.GC_BGD
    if (gc == cv2.GC_BGD).sum() == 0:
        raise NoGarmentFound("no pixel looks like the table: is the table model right for this image?")
    if cfg.min_table_blob_fraction > 0:
        # sure-table blobs enclosed by the garment (a shadow in a fold the colour of wood) must not
        # cut it as hard constraints: small ones start as probable table, GrabCut decides
        nb, blab, bstats, _ = cv2.connectedComponentsWithStats((gc == cv2.GC_BGD).astype(np.uint8),
                                                                connectivity=4)
        small_blob = bstats[:, cv2.CC_STAT_AREA] < cfg.min_table_blob_fraction * w * h
        small_blob[0] = False
        if small_blob.any():
            gc[small_blob[blab]] = cv2.GC_PR_BGD
    # GrabCut only where a garment can be: the bounding box of the opened foreground plus a margin
    sure = cv2.morphologyEx((tri == 2).astype(np.uint8), cv2.MORPH_OPEN, np.ones((5, 5), np.uint8))
    # a garment of the minimum size has a solid core of at least a quarter of that size
    if sure.sum() < 0.25 * cfg.min_area_fraction * w * h:
        raise NoGarmentFound("no garment-sized region unlike the table: no garment in the image")
    solid = None
    if cfg.sure_fg_radius_px > 0:
        # solid blocks of foreground (not thin streaks of wood grain): the garment's core
        k = 2 * cfg.sure_fg_radius_px + 1
        solid = cv2.morphologyEx((tri == 2).astype(np.uint8), cv2.MORPH_OPEN, np.ones((k, k), np.uint8))
    ys, xs = np.nonzero(sure)
    pad = cfg.grabcut_margin_px
    y0, y1 = max(int(ys.min()) - pad, 0), min(int(ys.max()) + pad + 1, h)
    x0, x1 = max(int(xs.min()) - pad, 0), min(int(xs.max()) + pad + 1, w)
    sub = np.ascontiguousarray(gc[y0:y1, x0:x1])
    if (sub == cv2.GC_BGD).sum() < cfg.grabcut_margin_px:
        if y0 == 0 and x0 == 0 and y1 == h and x1 == w:
            raise GarmentTouchesBorder("the garment fills the image; its outline is incomplete")
        raise NoGarmentFound("no table around the garment-like region: no garment in the image")
    # optionally GrabCut sees the colours under flat light (divided by the light field)
    flat = small if not cfg.grabcut_flat_light else np.clip(
        small.astype(np.float32) / light_small[..., None], 0, 255).astype(np.uint8)
    roi_img = np.ascontiguousarray(flat[y0:y1, x0:x1])
    init = sub.copy()
    bgd, fgd = _grabcut_models(roi_img, sub, cfg)
    _grabcut(roi_img, sub, bgd, fgd, cfg)
    if solid is not None:
        # a garment close to the table's colour can make GrabCut drop most of it (its colour
        # models swap); then it is run again with the solid core fixed as garment
        core = solid[y0:y1, x0:x1].astype(bool)
        kept = _largest(((sub == cv2.GC_FGD) | (sub == cv2.GC_PR_FGD)).astype(np.uint8))
        if core.any() and (kept & core).sum() < cfg.grabcut_keep_fraction * core.sum():
            sub = init
            sub[core] = cv2.GC_FGD
            bgd, fgd = _grabcut_models(roi_img, sub, cfg)
            _grabcut(roi_img, sub, bgd, fgd, cfg)
    fg = np.zeros((h, w), np.uint8)
    fg[y0:y1, x0:x1] = (sub == cv2.GC_FGD) | (sub == cv2.GC_PR_FGD)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(fg, connectivity=8)
    if n <= 1:
        raise NoGarmentFound("segmentation found no garment region")
    best = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    area = int(stats[best, cv2.CC_STAT_AREA])
    if area < cfg.min_area_fraction * w * h:
        raise NoGarmentFound(f"the largest garment-like region covers {100.0 * area / (w * h):.2f} % of "
                             f"the image, below min_area_fraction {100.0 * cfg.min_area_fraction:.2f} %")
    x0, y0, bw, bh = (int(stats[best, t]) for t in (cv2.CC_STAT_LEFT, cv2.CC_STAT_TOP,
                                                    cv2.CC_STAT_WIDTH, cv2.CC_STAT_HEIGHT))
    m = cfg.border_margin_px
    if x0 < m or y0 < m or x0 + bw > w - m or y0 + bh > h - m:
        raise GarmentTouchesBorder("the garment touches the image border; its outline is incomplete")
    region = (labels == best).astype(np.uint8)
    # fill holes: keep the outer border only
    outer, _ = cv2.findContours(region, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    region = np.zeros_like(region)
    cv2.drawContours(region, outer, -1, 1, thickness=cv2.FILLED)
    full = _refine(img, region, small, model, cfg, corr, light_small, tri)
    if cfg.spur_radius_px > 0:
        # spurs and notches of a few pixels (noise at the border) would draw polygon vertices
        # with absurd angles; an opening then a closing by a small disc removes them
        r = cfg.spur_radius_px
        disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
        full = cv2.morphologyEx(cv2.morphologyEx(full, cv2.MORPH_OPEN, disc), cv2.MORPH_CLOSE, disc)
    # specks the per-pixel relabelling may leave are not the largest outline, so they drop out
    cs, _ = cv2.findContours(full, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not cs:
        raise NoGarmentFound("no garment outline after refinement")
    contour = max(cs, key=cv2.contourArea).reshape(-1, 2)
    return Segmentation(contour, full.astype(bool), tri)


def _bilinear(field: NDArray, x: NDArray, y: NDArray) -> NDArray:
    """`field` (h, w) sampled bilinearly at (x, y), edges replicated."""
    h, w = field.shape
    x = np.clip(x, 0.0, w - 1.0)
    y = np.clip(y, 0.0, h - 1.0)
    xi = np.minimum(x.astype(np.intp), w - 2) if w > 1 else np.zeros(len(x), np.intp)
    yi = np.minimum(y.astype(np.intp), h - 2) if h > 1 else np.zeros(len(y), np.intp)
    fx, fy = x - xi, y - yi
    f = field
    if w == 1 or h == 1:
        return f[yi, xi].astype(np.float32)
    top = f[yi, xi] * (1 - fx) + f[yi, xi + 1] * fx
    bot = f[yi + 1, xi] * (1 - fx) + f[yi + 1, xi + 1] * fx
    return (top * (1 - fy) + bot * fy).astype(np.float32)


def _refine(img: NDArray, region: NDArray, small: NDArray, model: TableModel,
            cfg: SegmentationConfig, corr: NDArray | None, light_small: NDArray,
            tri: NDArray | None = None) -> NDArray:
    """Full-resolution mask: the coarse region upsampled, its border re-labelled per pixel.

    Only a box around the garment is processed, and colours are read only at the band pixels
    still unlabelled; band pixels are labelled by the likelihood ratio of a Gaussian of the
    garment's colour (from the coarse interior) against the table GMM. `light_small` is the
    light field (learned gain times this image's correction) at work size; it is sampled
    bilinearly at the band pixels.
    """
    rows, cols = img.shape[:2]
    h, w = region.shape
    sx, sy = cols / w, rows / h
    band_r = cfg.refine_band_px
    ly, lx = np.nonzero(region)
    pad = 2 * band_r + int(np.ceil(max(sx, sy)))
    x0, x1 = max(int(lx.min() * sx) - pad, 0), min(int((lx.max() + 1) * sx) + pad, cols)
    y0, y1 = max(int(ly.min() * sy) - pad, 0), min(int((ly.max() + 1) * sy) + pad, rows)
    # bilinear upsampling of the box, pixel centres aligned as in cv2.resize
    warp = np.array([[1 / sx, 0, (x0 + 0.5) / sx - 0.5], [0, 1 / sy, (y0 + 0.5) / sy - 0.5]])
    up = cv2.warpAffine(region.astype(np.float32), warp, (x1 - x0, y1 - y0),
                        flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_CONSTANT)
    roi = (up >= 0.5).astype(np.uint8)
    if band_r > 0:
        inner = cv2.erode(region, np.ones((3, 3), np.uint8)).astype(bool)
        if inner.sum() < 10:
            inner = region.astype(bool)
        nsmall = normalise(small, model.gain)
        if corr is not None:
            nsmall = nsmall / np.exp(corr)[..., None]
        gsmall = nsmall[inner].astype(float)
        gmean = gsmall.mean(axis=0)
        gcov = covariance(gsmall) + np.eye(3) * cfg.garment_var_floor
        # a square band (Chebyshev radius): OpenCV's square morphology is separable, 5x faster
        kernel = np.ones((2 * band_r + 1, 2 * band_r + 1), np.uint8)
        light_small = np.ascontiguousarray(light_small, np.float32)
        roi_img = img[y0:y1, x0:x1]
        # label cache, as 0/255 masks (OpenCV's SIMD mask operations; numpy's are several times
        # slower on a megapixel box): `seen` labelled, `cloth` labelled garment
        seen = np.zeros(roi.shape, np.uint8)
        cloth = np.zeros(roi.shape, np.uint8)

        def label(todo: NDArray) -> None:
            pts = cv2.findNonZero(todo)
            if pts is None:
                return
            pts = pts.reshape(-1, 2)
            bx, by = pts[:, 0], pts[:, 1]
            px = roi_img[by, bx]
            light = _bilinear(light_small, (bx + x0 + 0.5) / sx - 0.5, (by + y0 + 0.5) / sy - 0.5)
            feats = px.astype(np.float32) / light[:, None]
            l_table = gaussian_log_likelihood(feats, model.weights, model.means, model.covariances)
            l_garm = gaussian_log_likelihood(feats, np.ones(1), gmean[None], gcov[None])
            lab = l_garm > l_table
            # clipped pixels (glare) keep the coarse label: their colour says nothing
            clipped = _clipped_px(px, cfg, model, light)
            lab[clipped] = roi[by[clipped], bx[clipped]] > 0
            seen[by, bx] = 255
            cloth[by, bx] = np.where(lab, 255, 0)

        # each pass relabels a band around the current border, so a slit closed at the coarse
        # resolution (the crotch of pants) can open by up to refine_band_px per pass
        for _ in range(cfg.refine_passes):
            band = cv2.compare(cv2.morphologyEx(roi, cv2.MORPH_GRADIENT, kernel), 0, cv2.CMP_GT)
            label(cv2.bitwise_and(band, cv2.bitwise_not(seen)))
            new = cv2.bitwise_or(cv2.bitwise_and(cloth, band),
                                 cv2.bitwise_and(roi * 255, cv2.bitwise_not(band)))
            new = cv2.compare(new, 0, cv2.CMP_GT) // 255
            if cv2.countNonZero(cv2.absdiff(new, roi)) == 0:
                break
            roi = new
        if cfg.open_slits and tri is not None:
            # work-size pixels unlike the garment's colour (a slit mixes table into them)
            m2 = mahalanobis2(nsmall.reshape(-1, 3), gmean, gcov).reshape(region.shape)
            doubt = (tri != 2) | (m2 > cfg.slit_mahalanobis ** 2)
            roi = _open_slits(roi, seen, cloth, label, doubt, region, warp, cfg)
    mask = np.zeros((rows, cols), np.uint8)
    mask[y0:y1, x0:x1] = roi
    return mask


def _open_slits(roi: NDArray, seen: NDArray, cloth: NDArray, label: Callable[[NDArray], None],
                doubt: NDArray, region: NDArray, warp: NDArray, cfg: SegmentationConfig) -> NDArray:
    """Open thin slits the coarse segmentation closed (a sleeve lying against the body, the
    crotch of pants): too long for the band passes, yet connected to the table outside.

    Full-resolution pixels inside the garment whose work-size pixel (or a neighbour) is in doubt
    (not sure garment in the trimap, or far from the garment's colour: `slit_mahalanobis`) are
    labelled per pixel (`label`, which fills the 0/255 caches `seen` and `cloth`); table-labelled
    ones that are connected to the table outside the garment through other table pixels, after
    an opening that cuts one-pixel chains of noise, are removed from the garment. Enclosed
    table-like blobs stay garment.
    """
    h, w = roi.shape
    doubt = cv2.dilate((doubt & (region > 0)).astype(np.uint8), np.ones((3, 3), np.uint8))
    up = cv2.warpAffine(doubt * 255, warp, (w, h), flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP,
                        borderMode=cv2.BORDER_CONSTANT)
    inside = cv2.compare(roi, 0, cv2.CMP_GT)
    label(cv2.bitwise_and(cv2.bitwise_and(up, inside), cv2.bitwise_not(seen)))
    table_like = cv2.bitwise_and(cv2.bitwise_and(seen, cv2.bitwise_not(cloth)), inside)
    r = cfg.slit_min_width_px // 2
    if r > 0:
        table_like = cv2.morphologyEx(table_like, cv2.MORPH_OPEN, np.ones((2 * r + 1, 2 * r + 1), np.uint8))
    # the box is padded beyond the coarse garment, so its border is table
    outside = _reaching_border(cv2.bitwise_or(table_like, cv2.bitwise_not(inside)))
    return np.where(outside, 0, roi).astype(np.uint8)
