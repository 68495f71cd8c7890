"""Garment segmentation (paper Sec. III-A): table-GMM trimap (Eq. 1) -> GrabCut -> outer border.

Steps: downsample to `work_size` (320x256); divide each pixel by the table's learned brightness
field; label by the table GMM's log-likelihood against P_F / P_B (Eq. 1); initialise GrabCut's
mask with the trimap (sure table fixed; foreground pixels start as probable garment, since 3 % of
table pixels are foreground by construction, unknown ones as probable table) inside the box of
the likely garment, and run at most 3 iterations; keep the largest connected region. The coarse
border is then refined at full resolution in a narrow band by a per-pixel likelihood ratio
between the table GMM and a Gaussian of the garment's colour, and the outer border of the
full-resolution mask is traced (OpenCV's border following).

Coarse to fine, the time where the information is: the table model labels the work-size image;
GrabCut iterates on its box at 1/`grabcut_scale` of the work size (a quarter of the pixels at 2;
sure table stays fixed at work size), then one GrabCut pass at work size places every pixel again
(`_work_size_pass`: a slit the coarse pass closed, the narrow end of a pants crotch, opens there;
with the coarse cut alone the held-out pants' mean landmark error grew from 4.8 to 5.2 px); only
the band around GrabCut's border is labelled at full resolution. GrabCut's time halves (about 9 ms
of 25 on a 1280x1024 image); Table I stays within 0.002 cm of iterating at work size.

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
* Speed: likelihoods in float32 with element-wise products (no BLAS threads) from the table
  model's cached Gaussian terms, colours read only at the band pixels (flat gathers), a square
  band (separable morphology), the band's masks as OpenCV 0/255 images.

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

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from .config import SegmentationConfig
from .errors import GarmentTouchesBorder, NoGarmentFound
from .table_model import (
    GaussianTerms,
    TableModel,
    binary_split_init,
    check_image,
    covariance,
    gain_field,
    mahalanobis2,
    normalise,
    ray_mahalanobis2,
)


@dataclass(frozen=True)
class Segmentation:
    contour: NDArray     # (P, 2) int outer border, full-resolution pixels
    mask: NDArray        # (rows, cols) bool at full resolution (region of interest filled)
    trimap: NDArray      # (h, w) uint8 at work size: 0 bg, 1 unknown, 2 fg
    doubt: str | None = None   # why this segmentation may be wrong (None: no reason known)


def table_log_likelihood(img: NDArray, model: TableModel, correction: NDArray | None = None) -> NDArray:
    colours = normalise(img, model.gain)
    if correction is not None:
        colours = colours / np.exp(correction)[..., None]
    return model.terms.log_likelihood(colours.reshape(-1, 3)).reshape(img.shape[:2])


def _clipped(img: NDArray, cfg: SegmentationConfig, model: TableModel,
             light: NDArray | None = None) -> NDArray:
    """Glare on the table: clipped channels have lost the colour, so the likelihood cannot judge.

    Two (not all) channels clipped with a hue still near the table's, or one channel clipped
    with the other two typical of the table (Mahalanobis distance of the 2-D marginal of a GMM
    component, after the light normalisation `light`, within `glare_mahalanobis`). A white
    garment clips all three and is left to the likelihood and GrabCut.
    """
    flat_light = None if light is None else np.asarray(light).reshape(-1)
    return _clipped_px(img.reshape(-1, 3), cfg, model, flat_light).reshape(img.shape[:2])


def _clipped_px(px: NDArray, cfg: SegmentationConfig, model: TableModel,
                light: NDArray | None = None) -> NDArray:
    """`_clipped` for (n, 3) uint8 pixels with their (n,) light (or None)."""
    level = cfg.saturation_level
    # per-channel comparisons: numpy reduces a length-3 last axis slowly
    clipped_channels = ((px[:, 0] >= level).view(np.uint8) + (px[:, 1] >= level).view(np.uint8)
                        + (px[:, 2] >= level).view(np.uint8))
    out = np.zeros(clipped_channels.shape, bool)
    if not clipped_channels.any():
        return out
    two_clipped = clipped_channels == 2
    if two_clipped.any():
        colours = px[two_clipped].astype(np.float32)
        chroma = colours / (colours.sum(axis=1, keepdims=True) + 1e-6)
        table_chroma = (model.means / model.means.sum(axis=1, keepdims=True)).astype(np.float32)
        distance = np.min(np.linalg.norm(chroma[:, None, :] - table_chroma[None], axis=2), axis=1)
        out[two_clipped] = distance < cfg.glare_chroma_tolerance
    one_clipped = clipped_channels == 1
    if one_clipped.any():
        colours = px[one_clipped].astype(np.float64)
        if light is not None:
            colours = colours / light[one_clipped][:, None]
        which = np.argmax(px[one_clipped] >= cfg.saturation_level, axis=1)
        ok = np.zeros(len(colours), bool)
        for channel in range(3):
            sel = which == channel
            if not sel.any():
                continue
            keep = [c for c in range(3) if c != channel]
            for k in range(len(model.weights)):
                mu = model.means[k, keep]
                cov = model.covariances[k][np.ix_(keep, keep)]
                d = colours[sel][:, keep] - mu
                distance2 = np.einsum("ij,jk,ik->i", d, np.linalg.inv(cov), d)
                ok[np.flatnonzero(sel)[distance2 < cfg.glare_mahalanobis ** 2]] = True
        out[one_clipped] = ok
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
    stride = cfg.light_sample_stride
    sampled = small[stride // 2::stride, stride // 2::stride]
    rows_sampled, cols_sampled = sampled.shape[:2]
    light = gain_field(model.gain, (h, w))[stride // 2::stride, stride // 2::stride]
    colours = (sampled.astype(np.float32) / light[..., None]).reshape(-1, 3)
    distance2, _ = ray_mahalanobis2(colours, model.weights, model.means, model.covariances)
    table_brightness = float(model.weights @ model.means.mean(axis=1))
    brightness = colours.mean(axis=1)
    target = np.log(np.maximum(brightness, 1.0) / table_brightness).astype(float)
    bound = cfg.light_max_log_change
    unclipped = (sampled < cfg.saturation_level).all(axis=2).ravel()
    ok = (distance2 < cfg.light_mahalanobis ** 2) & (brightness > 1.0) & unclipped & (np.abs(target) < bound)
    if ok.sum() < cfg.light_min_fraction * rows_sampled * cols_sampled:
        return np.zeros((h, w), np.float32)
    yy, xx = np.divmod(np.arange(rows_sampled * cols_sampled), cols_sampled)
    A = _poly_terms((xx * stride + stride // 2 + 0.5) / w, (yy * stride + stride // 2 + 0.5) / h)
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
    resid = (target - np.einsum("ij,j->i", A, coeffs)).reshape(rows_sampled, cols_sampled)
    inliers = keep.reshape(rows_sampled, cols_sampled)
    # per grid cell: the mean residual of the quadratic's inliers (sums over cell blocks)
    cell_rows = np.arange(rows) * rows_sampled // rows
    cell_cols = np.arange(cols) * cols_sampled // cols
    def cell_sums(values: NDArray) -> NDArray:
        return np.add.reduceat(np.add.reduceat(values, cell_rows, axis=0), cell_cols, axis=1)

    sums = cell_sums(np.where(inliers, resid, 0.0))
    counts = cell_sums(inliers.astype(float))
    sizes = np.outer(np.diff(np.append(cell_rows, rows_sampled)), np.diff(np.append(cell_cols, cols_sampled)))
    grid = np.where(counts >= cfg.light_min_fraction * sizes, sums / np.maximum(counts, 1.0), 0.0)
    grid = cv2.GaussianBlur(grid.astype(np.float32), (3, 3), 0)
    # the quadratic, separable: row terms + column terms + the cross term
    u = ((np.arange(w, dtype=np.float32) + 0.5) / w)[None, :]
    v = ((np.arange(h, dtype=np.float32) + 0.5) / h)[:, None]
    c = coeffs.astype(np.float32)
    field = (c[0] + c[1] * u + c[3] * u * u) + (c[2] * v + c[5] * v * v) + c[4] * (v * u)
    field = field + cv2.resize(grid, (w, h), interpolation=cv2.INTER_LINEAR)
    return np.clip(field, -bound, bound).astype(np.float32)


def _borrow_labels(trimap_labels: NDArray, clipped: NDArray, table_hue: NDArray, brighter: NDArray,
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
    garment_votes = (trimap_labels == 2) & ~table_hue & ~brighter & known
    table_votes = ((trimap_labels == 0) | table_hue) & known
    garment = cv2.GaussianBlur(garment_votes.astype(np.float32), (0, 0), sigma)
    table = cv2.GaussianBlur(table_votes.astype(np.float32), (0, 0), sigma)
    return clipped & (garment > table)


def trimap(log_likelihood: NDArray, model: TableModel) -> NDArray:
    """Eq. 1: 2 = foreground (p < P_F), 0 = background (p > P_B), 1 = unknown."""
    labels = np.ones(log_likelihood.shape, np.uint8)
    labels[log_likelihood < model.threshold_fg] = 2
    labels[log_likelihood > model.threshold_bg] = 0
    return labels


def _gmm_param(px: NDArray, cfg: SegmentationConfig) -> NDArray:
    """One GrabCut colour model (OpenCV's packed 1x65 layout for 5 components: weights, means,
    covariances) initialised by the binary-split palette algorithm with `grabcut_components`
    components; the others get weight 0, which OpenCV never assigns a pixel to, so GrabCut
    re-estimates exactly that many components in every iteration (the paper's 3)."""
    k_max = 5
    out = np.zeros((1, 13 * k_max), np.float64)
    colours = px.astype(np.float64)
    if len(colours) < 2:
        colours = np.vstack([colours, np.full((2, 3), 128.0)])[:2] if len(colours) else np.full((2, 3), 128.0)
    component_of = binary_split_init(colours, min(cfg.grabcut_components, k_max))
    var_floor = np.eye(3) * cfg.grabcut_var_floor
    for c in range(min(cfg.grabcut_components, k_max)):
        members = colours[component_of == c]
        if len(members) < 2:
            continue
        out[0, c] = len(members) / len(colours)
        out[0, k_max + 3 * c:k_max + 3 * c + 3] = members.mean(axis=0)
        out[0, 4 * k_max + 9 * c:4 * k_max + 9 * c + 9] = (covariance(members) + var_floor).ravel()
    return out


def _grabcut_models(img: NDArray, labels: NDArray, cfg: SegmentationConfig) -> tuple[NDArray, NDArray]:
    """Background and foreground GMMs from the trimap-initialised mask (sampled pixels).

    Replaces OpenCV's own initialisation (k-means with 5 components, most of GrabCut's time at
    this size); GrabCut is then run in GC_EVAL mode, its usual iterations from these models.
    """
    stride = cfg.grabcut_sample_stride
    sampled_labels, sampled = labels[::stride, ::stride], img[::stride, ::stride]
    garment = (sampled_labels == cv2.GC_FGD) | (sampled_labels == cv2.GC_PR_FGD)
    return _gmm_param(sampled[~garment], cfg), _gmm_param(sampled[garment], cfg)


def _grabcut(img: NDArray, mask: NDArray, background: NDArray, foreground: NDArray,
             cfg: SegmentationConfig) -> None:
    """GrabCut (GC_EVAL from the given colour models) for at most `grabcut_iterations`, one at a time
    (the same result as one call), stopping once an iteration changes fewer than
    `grabcut_converged_fraction` of the labels: those are border pixels, which the full-resolution
    refinement labels again anyway."""
    for _ in range(cfg.grabcut_iterations):
        before = mask.copy()
        # no rectangle in GC_EVAL mode (OpenCV's stubs want one)
        cv2.grabCut(img, mask, None, background, foreground, 1, cv2.GC_EVAL)  # type: ignore[call-overload]
        if np.count_nonzero(before != mask) < cfg.grabcut_converged_fraction * mask.size:
            return


def _reaching_border(mask: NDArray) -> NDArray:
    """255 where a pixel of the uint8 mask is 4-connected within it to the array's border, else 0:
    a flood fill of the mask framed by one pixel, from the frame."""
    # OpenCV compares with a scalar; its stubs only know arrays
    framed = cv2.copyMakeBorder(cv2.compare(mask, 0, cv2.CMP_NE), 1, 1, 1, 1,  # type: ignore[call-overload]
                                cv2.BORDER_CONSTANT, value=255)
    cv2.floodFill(framed, None, (0, 0), 128, flags=4)
    return cv2.compare(framed[1:-1, 1:-1], 128, cv2.CMP_EQ)  # type: ignore[call-overload]


def _largest(mask: NDArray) -> NDArray:
    """The largest 8-connected region of a uint8 mask (bool; all False if empty)."""
    count, region_of_pixel, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if count <= 1:
        return np.zeros(mask.shape, bool)
    return region_of_pixel == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))


@dataclass(frozen=True)
class WorkImage:
    """The image at work size and what the steps share about it."""

    pixels: NDArray               # (h, w, 3) uint8, the image downsampled to `work_size`
    correction: NDArray | None    # (h, w) this image's log-brightness change (`light_correction`)
    light: NDArray                # (h, w) the learned brightness field times that change
    trimap: NDArray               # (h, w) uint8 of Eq. 1: 0 table, 1 unknown, 2 garment
    saturated: NDArray            # (h, w) bool, clipped pixels (glare)


def segment(image: NDArray, model: TableModel, cfg: SegmentationConfig) -> Segmentation:
    """The garment's outer border in full-resolution pixels; raises a `PerceptionError` subclass."""
    img = check_image(image)
    work = work_image(img, model, cfg)
    labels = grabcut_labels(work, model, cfg)
    garment = grabcut_garment(work, labels, cfg)
    region = garment_region(garment, cfg)
    mask = full_resolution_mask(img, region, work, model, cfg)
    return Segmentation(outer_contour(mask), mask.astype(bool), work.trimap)


def work_image(img: NDArray, model: TableModel, cfg: SegmentationConfig) -> WorkImage:
    """Downsample, fit this image's light, label every pixel by the table GMM (Eq. 1).

    Clipped pixels (glare) have lost their colour: they are never sure garment (probably table
    unless among garment, see `grabcut_labels`).
    """
    w, h = cfg.work_size
    small = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
    correction = light_correction(small, model, cfg) if cfg.adapt_light else None
    light = gain_field(model.gain, (h, w))
    if correction is not None:
        light = light * np.exp(correction)
    colours = (small / light[..., None]).reshape(-1, 3)
    labels = trimap(model.terms.log_likelihood(colours).reshape(h, w), model)
    saturated = _clipped(small, cfg, model, light)
    labels[saturated & (labels == 2)] = 1
    if not (labels == 2).any():
        raise NoGarmentFound("no pixel is unlike the table: no garment in the image")
    return WorkImage(small, correction, light, labels, saturated)


def grabcut_labels(work: WorkImage, model: TableModel, cfg: SegmentationConfig) -> NDArray:
    """GrabCut's initial mask (work size) from the trimap.

    Foreground labels are "probable": by construction 3 % of table pixels fall below P_F, and
    GrabCut must be free to relabel them; only sure table pixels are fixed, with the unknown
    pixels of the table's colour that reach the table around the garment
    (`unknown_table_hue_fixed`). Small sure-table blobs enclosed by the garment are only probable
    table (`min_table_blob_fraction`).
    """
    likely = (work.trimap == 2) & ~work.saturated
    if work.saturated.any():
        likely |= _glare_among_garment(work, model, cfg)
    labels = np.where(work.trimap == 0, cv2.GC_BGD,
                      np.where(likely, cv2.GC_PR_FGD, cv2.GC_PR_BGD)).astype(np.uint8)
    if cfg.unknown_table_hue_fixed:
        labels[_table_hued_reaching_table(work, model, cfg)] = cv2.GC_BGD
    if (labels == cv2.GC_BGD).sum() == 0:
        raise NoGarmentFound("no pixel looks like the table: is the table model right for this image?")
    if cfg.min_table_blob_fraction > 0:
        labels[_small_table_blobs(labels, cfg)] = cv2.GC_PR_BGD
    return labels


def _glare_among_garment(work: WorkImage, model: TableModel, cfg: SegmentationConfig) -> NDArray:
    """Clipped pixels that start GrabCut as probable garment (`_borrow_labels`).

    The colour test runs only where it can change a vote (not sure table, unclipped, within reach
    of a clipped pixel), for speed.
    """
    reach = 2 * int(np.ceil(3 * cfg.glare_context_px)) + 1
    near = cv2.dilate(work.saturated.view(np.uint8), np.ones((reach, reach), np.uint8)) > 0
    tested = (work.trimap != 0) & near & ~work.saturated
    colours = work.pixels[tested].astype(np.float32) / work.light[tested][:, None]
    distance2, brightness = ray_mahalanobis2(colours, model.weights, model.means, model.covariances)
    table_hue = np.zeros(work.trimap.shape, bool)
    brighter = np.zeros(work.trimap.shape, bool)
    table_hue[tested] = distance2 < cfg.light_mahalanobis ** 2
    brighter[tested] = brightness > cfg.glare_max_brightness
    return _borrow_labels(work.trimap, work.saturated, table_hue, brighter, cfg.glare_context_px)


def _table_hued_reaching_table(work: WorkImage, model: TableModel, cfg: SegmentationConfig) -> NDArray:
    """Unknown pixels of the table's colour, at a brightness the light allows, that reach the table
    around the garment through such pixels (a darker plank beside the garment).

    Left free, GrabCut's garment model can take a whole plank. Reaching out matters: a wood-hued
    garment has pixels like these inside, enclosed by garment.
    """
    tested = (work.trimap == 1) & ~work.saturated
    colours = work.pixels[tested].astype(np.float32) / work.light[tested][:, None]
    distance2, brightness = ray_mahalanobis2(colours, model.weights, model.means, model.covariances)
    table_hued = np.zeros(work.trimap.shape, np.uint8)
    table_hued[tested] = (distance2 < cfg.light_mahalanobis ** 2) & (
        np.abs(np.log(np.maximum(brightness, 1e-6))) < cfg.light_max_log_change)
    # an opening cuts one-pixel chains (wood grain, noise) that would lead into a garment
    wood = cv2.morphologyEx(table_hued, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    return (wood > 0) & (_reaching_border(wood | (work.trimap == 0).view(np.uint8)) > 0)


def _small_table_blobs(labels: NDArray, cfg: SegmentationConfig) -> NDArray:
    """Sure-table blobs smaller than `min_table_blob_fraction` of the image (a shadow in a fold the
    colour of wood, enclosed by the garment): they must not cut it as hard constraints."""
    h, w = labels.shape
    _, blob_of_pixel, blob_stats, _ = cv2.connectedComponentsWithStats(
        (labels == cv2.GC_BGD).astype(np.uint8), connectivity=4)
    small_blob = blob_stats[:, cv2.CC_STAT_AREA] < cfg.min_table_blob_fraction * w * h
    small_blob[0] = False   # label 0: the pixels that are not sure table
    return small_blob[blob_of_pixel]


def _grabcut_box(trimap_labels: NDArray, cfg: SegmentationConfig) -> tuple[slice, slice]:
    """Where a garment can be: the bounding box of the sure garment's dense core (windows of
    `core_window_px` at least `core_density` full) plus `grabcut_margin_px`."""
    h, w = trimap_labels.shape
    window = (cfg.core_window_px, cfg.core_window_px)
    sure = cv2.blur((trimap_labels == 2).astype(np.float32), window) >= cfg.core_density
    # a garment of the minimum size has a solid core of at least a quarter of that size
    if sure.sum() < 0.25 * cfg.min_area_fraction * w * h:
        raise NoGarmentFound("no garment-sized region unlike the table: no garment in the image")
    ys, xs = np.nonzero(sure)
    pad = cfg.grabcut_margin_px
    y0, y1 = max(int(ys.min()) - pad, 0), min(int(ys.max()) + pad + 1, h)
    x0, x1 = max(int(xs.min()) - pad, 0), min(int(xs.max()) + pad + 1, w)
    return slice(y0, y1), slice(x0, x1)


def grabcut_garment(work: WorkImage, labels: NDArray, cfg: SegmentationConfig) -> NDArray:
    """GrabCut's garment pixels (work size, uint8 0/1), run in the box around the likely garment.

    With `grabcut_scale` > 1 GrabCut iterates on the box at 1/that of the work size (`_coarse_box`),
    then places every pixel in one pass at work size (`_work_size_pass`). A garment close to the table's
    colour can make GrabCut drop most of it (its colour models swap): if its largest region
    keeps less than `grabcut_keep_fraction` of the solid core of the sure garment (surviving an
    opening of `sure_fg_radius_px`), it is run again with that core fixed as garment.
    """
    h, w = work.trimap.shape
    box = _grabcut_box(work.trimap, cfg)
    in_box = np.ascontiguousarray(labels[box])
    if (in_box == cv2.GC_BGD).sum() < cfg.grabcut_margin_px:
        if in_box.shape == (h, w):
            raise GarmentTouchesBorder("the garment fills the image; its outline is incomplete")
        raise NoGarmentFound("no table around the garment-like region: no garment in the image")
    # optionally GrabCut sees the colours under flat light (divided by the light field)
    colours = work.pixels if not cfg.grabcut_flat_light else np.clip(
        work.pixels.astype(np.float32) / work.light[..., None], 0, 255).astype(np.uint8)
    box_image, coarse = _coarse_box(np.ascontiguousarray(colours[box]), in_box, cfg.grabcut_scale)
    initial = coarse.copy()
    background, foreground = _grabcut_models(box_image, coarse, cfg)
    _grabcut(box_image, coarse, background, foreground, cfg)
    core_fixed = None   # the work-size core fixed as garment when GrabCut ran again
    if cfg.sure_fg_radius_px > 0:
        # solid blocks of foreground (not thin streaks of wood grain): the garment's core
        size = 2 * cfg.sure_fg_radius_px + 1
        solid = cv2.morphologyEx((work.trimap == 2).astype(np.uint8), cv2.MORPH_OPEN,
                                 np.ones((size, size), np.uint8))
        core = _shrink(solid[box].astype(np.float32), coarse.shape) >= 0.5
        kept = _largest(((coarse == cv2.GC_FGD) | (coarse == cv2.GC_PR_FGD)).astype(np.uint8))
        if core.any() and (kept & core).sum() < cfg.grabcut_keep_fraction * core.sum():
            coarse = initial
            coarse[core] = cv2.GC_FGD
            core_fixed = solid[box] > 0
            background, foreground = _grabcut_models(box_image, coarse, cfg)
            _grabcut(box_image, coarse, background, foreground, cfg)
    cut = (coarse == cv2.GC_FGD) | (coarse == cv2.GC_PR_FGD)
    garment = np.zeros((h, w), np.uint8)
    if cut.shape != in_box.shape:
        cut = _work_size_pass(np.ascontiguousarray(colours[box]), cut, in_box, core_fixed,
                              background, foreground, cfg)
    garment[box] = cut
    return garment


def _work_size_pass(box_image: NDArray, coarse_cut: NDArray, in_box: NDArray, core_fixed: NDArray | None,
                    background: NDArray, foreground: NDArray, cfg: SegmentationConfig) -> NDArray:
    """One GrabCut pass at work size from the coarse cut (bool, coarse): the graph cut places every
    pixel again at work size, so a slit the coarse pass closed opens and a thin part it lost comes
    back. Its colour models are learned again from the upsampled cut at work size; if that pass
    adds more than `grabcut_max_growth` of the cut's area (held-out garments add at most 1.2 %), it
    took in table (a band of over-exposed table beside a pale garment, 9 %) and the pass is made
    again with the coarse models, frozen. Sure table, and the core when it was fixed, stay fixed."""
    box_h, box_w = in_box.shape
    upsampled = cv2.resize(coarse_cut.astype(np.float32), (box_w, box_h),
                           interpolation=cv2.INTER_LINEAR) >= 0.5
    labels = np.where(in_box == cv2.GC_BGD, cv2.GC_BGD,
                      np.where(upsampled, cv2.GC_PR_FGD, cv2.GC_PR_BGD)).astype(np.uint8)
    if core_fixed is not None:
        labels[core_fixed & (in_box != cv2.GC_BGD)] = cv2.GC_FGD
    initial = labels.copy()
    # (GrabCut learns into the models it is given: the coarse ones are kept for the frozen pass)
    cv2.grabCut(box_image, labels, None, background.copy(), foreground.copy(), 1,  # type: ignore[call-overload]
                cv2.GC_EVAL)
    cut = (labels == cv2.GC_FGD) | (labels == cv2.GC_PR_FGD)
    if np.count_nonzero(cut & ~upsampled) <= cfg.grabcut_max_growth * np.count_nonzero(upsampled):
        return cut
    cv2.grabCut(box_image, initial, None, background, foreground, 1,  # type: ignore[call-overload]
                cv2.GC_EVAL_FREEZE_MODEL)
    return (initial == cv2.GC_FGD) | (initial == cv2.GC_PR_FGD)


def _shrink(values: NDArray, shape: tuple[int, ...]) -> NDArray:
    """`values` (float32) averaged down to `shape` (rows, cols); as they are if already that size."""
    if values.shape[:2] == shape[:2]:
        return values
    return cv2.resize(values, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)


def _coarse_box(box_image: NDArray, in_box: NDArray, scale: int) -> tuple[NDArray, NDArray]:
    """The box's colours and GrabCut labels at 1/`scale` of the work size, by majority: a coarse
    pixel is sure table if at least half its work pixels are (fewer left GrabCut free to join
    table-coloured specks at the image border to the garment), probable garment if at least half
    are, else probable table. The garment's edge pixels it fixes as table are the refinement's."""
    if scale == 1:
        return box_image, in_box
    box_h, box_w = in_box.shape
    size = (max(box_w // scale, 1), max(box_h // scale, 1))
    small = cv2.resize(box_image, size, interpolation=cv2.INTER_AREA)
    table = cv2.resize((in_box == cv2.GC_BGD).astype(np.float32), size, interpolation=cv2.INTER_AREA)
    garment = cv2.resize((in_box == cv2.GC_PR_FGD).astype(np.float32), size, interpolation=cv2.INTER_AREA)
    labels = np.where(table >= 0.5, cv2.GC_BGD,
                      np.where(garment >= 0.5, cv2.GC_PR_FGD, cv2.GC_PR_BGD)).astype(np.uint8)
    return small, labels


def garment_region(garment: NDArray, cfg: SegmentationConfig) -> NDArray:
    """The largest garment region (work size, uint8 0/1) with its holes filled; it must be large
    enough (`min_area_fraction`) and keep `border_margin_px` from the image border."""
    h, w = garment.shape
    count, region_of_pixel, stats, _ = cv2.connectedComponentsWithStats(garment, connectivity=8)
    if count <= 1:
        raise NoGarmentFound("segmentation found no garment region")
    best = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    area = int(stats[best, cv2.CC_STAT_AREA])
    if area < cfg.min_area_fraction * w * h:
        raise NoGarmentFound(f"the largest garment-like region covers {100.0 * area / (w * h):.2f} % of "
                             f"the image, below min_area_fraction {100.0 * cfg.min_area_fraction:.2f} %")
    x0, y0, box_w, box_h = (int(stats[best, k]) for k in (cv2.CC_STAT_LEFT, cv2.CC_STAT_TOP,
                                                          cv2.CC_STAT_WIDTH, cv2.CC_STAT_HEIGHT))
    margin = cfg.border_margin_px
    if x0 < margin or y0 < margin or x0 + box_w > w - margin or y0 + box_h > h - margin:
        raise GarmentTouchesBorder("the garment touches the image border; its outline is incomplete")
    region = (region_of_pixel == best).astype(np.uint8)
    # fill holes: keep the outer border only
    outer, _ = cv2.findContours(region, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    region = np.zeros_like(region)
    cv2.drawContours(region, outer, -1, 1, thickness=cv2.FILLED)
    return region


def full_resolution_mask(img: NDArray, region: NDArray, work: WorkImage, model: TableModel,
                         cfg: SegmentationConfig) -> NDArray:
    """The work-size region refined at full resolution (`_refine`; uint8 0/1, image size)."""
    return _refine(img, region, work.pixels, model, cfg, work.light, work.trimap)


def outer_contour(mask: NDArray) -> NDArray:
    """The outer border (P, 2) of the mask's largest outline; specks the per-pixel relabelling may
    leave are not the largest, so they drop out."""
    outlines, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not outlines:
        raise NoGarmentFound("no garment outline after refinement")
    return max(outlines, key=cv2.contourArea).reshape(-1, 2)


def _bilinear(field: NDArray, x: NDArray, y: NDArray) -> NDArray:
    """`field` (h, w) sampled bilinearly at (x, y), edges replicated (float32, flat gathers)."""
    h, w = field.shape
    flat = np.ascontiguousarray(field, np.float32).reshape(-1)
    x = np.clip(np.asarray(x, np.float32), 0.0, w - 1.0)
    y = np.clip(np.asarray(y, np.float32), 0.0, h - 1.0)
    xi = np.minimum(x.astype(np.int32), max(w - 2, 0))
    yi = np.minimum(y.astype(np.int32), max(h - 2, 0))
    fx, fy = x - xi.astype(np.float32), y - yi.astype(np.float32)
    corner = yi * w + xi
    right, below = min(w - 1, 1), w * min(h - 1, 1)
    top = flat.take(corner) * (1 - fx) + flat.take(corner + right) * fx
    bottom = flat.take(corner + below) * (1 - fx) + flat.take(corner + below + right) * fx
    return top * (1 - fy) + bottom * fy


class _BoxLabeller:
    """Labels full-resolution pixels of a box around the garment as garment or table, each once,
    by the likelihood ratio of a Gaussian of the garment's colour against the table GMM.

    Colours are read only at the pixels asked for. The labels are kept as 0/255 masks (OpenCV's
    SIMD mask operations; numpy's are several times slower on a megapixel box): `seen` labelled,
    `cloth` labelled garment. Clipped pixels (glare) keep the coarse label: their colour says
    nothing. `light_small` (learned gain times this image's correction, work size) is sampled
    bilinearly at the labelled pixels.
    """

    def __init__(self, img: NDArray, box: tuple[int, int, int, int], scale: tuple[float, float],
                 light_small: NDArray, garment_mean: NDArray, garment_cov: NDArray, model: TableModel,
                 cfg: SegmentationConfig):
        self.pixels = img.reshape(-1, 3)       # the whole image's pixels, read at flat indices
        self.cols = img.shape[1]
        self.box = box                         # (x0, y0, x1, y1) in the image
        self.scale = scale                     # full-resolution pixels per work pixel (x, y)
        self.light_small = np.ascontiguousarray(light_small, np.float32)
        self.garment = GaussianTerms.of(np.ones(1), garment_mean[None], garment_cov[None])
        self.model, self.cfg = model, cfg
        x0, y0, x1, y1 = box
        self.seen = np.zeros((y1 - y0, x1 - x0), np.uint8)
        self.cloth = np.zeros((y1 - y0, x1 - x0), np.uint8)

    def label(self, todo: NDArray, coarse: NDArray) -> None:
        """Label the pixels of the 0/255 box mask `todo`; clipped ones take their label in `coarse`."""
        index = _nonzero_indices(todo)
        if len(index) == 0:
            return
        x0, y0, x1, _ = self.box
        by, bx = np.divmod(index, x1 - x0)
        sx, sy = self.scale
        px = self.pixels.take((by + y0) * self.cols + (bx + x0), axis=0)
        light = _bilinear(self.light_small, (bx + x0 + 0.5) / sx - 0.5, (by + y0 + 0.5) / sy - 0.5)
        colours = px.astype(np.float32) / light[:, None]
        model = self.model
        is_garment = self.garment.log_likelihood(colours) > model.terms.log_likelihood(colours)
        clipped = _clipped_px(px, self.cfg, model, light)
        is_garment[clipped] = coarse.reshape(-1)[index[clipped]] > 0
        cv2.bitwise_or(self.seen, todo, dst=self.seen)
        self.cloth.reshape(-1)[index[is_garment]] = 255


def _nonzero_indices(mask: NDArray) -> NDArray:
    """Flat indices of the non-zero pixels of a contiguous uint8 mask, eight pixels a word at a
    time (a band is a few percent of its box; OpenCV's findNonZero reads one pixel at a time)."""
    flat = mask.reshape(-1)
    whole = len(flat) // 8 * 8
    words = np.flatnonzero(flat[:whole].view(np.uint64))
    candidates = (words[:, None] * 8 + np.arange(8)).reshape(-1)
    return np.concatenate([candidates[flat[candidates] != 0], whole + np.flatnonzero(flat[whole:])])


def _refine(img: NDArray, region: NDArray, small: NDArray, model: TableModel, cfg: SegmentationConfig,
            light_small: NDArray, trimap_labels: NDArray | None = None) -> NDArray:
    """Full-resolution mask (uint8 0/1): the coarse region upsampled, its border re-labelled per
    pixel (`_BoxLabeller`), thin slits opened (`_open_slits`), without spurs and notches of a few
    pixels (an opening then a closing by a disc of `spur_radius_px`: they would draw polygon
    vertices with absurd angles).

    Only a box around the garment is processed, as 0/255 masks. The garment's colour is learned
    from the coarse interior, under the light field.
    """
    rows, cols = img.shape[:2]
    h, w = region.shape
    sx, sy = cols / w, rows / h
    band_radius = cfg.refine_band_px
    region_ys, region_xs = np.nonzero(region)
    pad = 2 * band_radius + int(np.ceil(max(sx, sy))) + cfg.spur_radius_px
    x0, x1 = max(int(region_xs.min() * sx) - pad, 0), min(int((region_xs.max() + 1) * sx) + pad, cols)
    y0, y1 = max(int(region_ys.min() * sy) - pad, 0), min(int((region_ys.max() + 1) * sy) + pad, rows)
    # bilinear upsampling of the box, pixel centres aligned as in cv2.resize
    warp = np.array([[1 / sx, 0, (x0 + 0.5) / sx - 0.5], [0, 1 / sy, (y0 + 0.5) / sy - 0.5]])
    upsampled = cv2.warpAffine(region * 255, warp, (x1 - x0, y1 - y0),
                               flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_CONSTANT)
    # OpenCV compares with a scalar; its stubs only know arrays
    roi = cv2.compare(upsampled, 128, cv2.CMP_GE)  # type: ignore[call-overload]
    if band_radius > 0:
        inner = cv2.erode(region, np.ones((3, 3), np.uint8)).astype(bool)
        if inner.sum() < 10:
            inner = region.astype(bool)
        garment_colours = (small[inner] / light_small[inner][:, None]).astype(float)
        garment_mean = garment_colours.mean(axis=0)
        garment_cov = covariance(garment_colours) + np.eye(3) * cfg.garment_var_floor
        labeller = _BoxLabeller(img, (x0, y0, x1, y1), (sx, sy), light_small, garment_mean, garment_cov,
                                model, cfg)
        roi = _follow_border(roi, labeller, cfg)
        if cfg.open_slits and trimap_labels is not None:
            # work-size pixels unlike the garment's colour (a slit mixes table into them); only
            # sure-garment pixels of the region need the distance
            sure = (trimap_labels == 2) & (region > 0)
            distance2 = mahalanobis2(small[sure] / light_small[sure][:, None], garment_mean, garment_cov)
            doubt = trimap_labels != 2
            doubt[sure] = distance2 > cfg.slit_mahalanobis ** 2
            roi = _open_slits(roi, labeller, doubt, region, warp, cfg)
    if cfg.spur_radius_px > 0:
        r = cfg.spur_radius_px
        disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
        roi = cv2.morphologyEx(cv2.morphologyEx(roi, cv2.MORPH_OPEN, disc), cv2.MORPH_CLOSE, disc)
    mask = np.zeros((rows, cols), np.uint8)
    mask[y0:y1, x0:x1] = cv2.bitwise_and(roi, 1)  # type: ignore[call-overload]
    return mask


def _follow_border(roi: NDArray, labeller: _BoxLabeller, cfg: SegmentationConfig) -> NDArray:
    """Relabel a band of `refine_band_px` around the border of the 0/255 mask `roi`,
    `refine_passes` times or until it stays: a slit closed at the coarse resolution (the crotch
    of pants) opens by up to the band's width per pass. After the first pass only the part of
    the box where the band can have moved is processed (within the band's radius of the pixels
    that changed): the same result, at the cost of the changes."""
    radius = cfg.refine_band_px
    # a square band (Chebyshev radius): OpenCV's square morphology is separable, 5x faster
    kernel = np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)
    rows, cols = roi.shape
    roi = roi.copy()
    x0, y0, x1, y1 = 0, 0, cols, rows
    for _ in range(cfg.refine_passes):
        # the band there, from the mask one radius further out (farther pixels do not reach it)
        ox0, oy0 = max(x0 - radius, 0), max(y0 - radius, 0)
        ox1, oy1 = min(x1 + radius, cols), min(y1 + radius, rows)
        band = np.ascontiguousarray(cv2.morphologyEx(roi[oy0:oy1, ox0:ox1], cv2.MORPH_GRADIENT, kernel)[
            y0 - oy0:y1 - oy0, x0 - ox0:x1 - ox0])
        area = (slice(y0, y1), slice(x0, x1))
        todo = np.zeros_like(roi)
        todo[area] = cv2.subtract(band, np.ascontiguousarray(labeller.seen[area]))
        labeller.label(todo, roi)
        current = np.ascontiguousarray(roi[area])
        new = cv2.bitwise_or(cv2.bitwise_and(np.ascontiguousarray(labeller.cloth[area]), band),
                             cv2.subtract(current, band))
        changed = cv2.findNonZero(cv2.absdiff(new, current))
        if changed is None:
            break
        roi[area] = new
        cx, cy, cw, ch = cv2.boundingRect(changed)
        x0, y0, x1, y1 = (max(x0 + cx - radius, 0), max(y0 + cy - radius, 0),
                          min(x0 + cx + cw + radius, cols), min(y0 + cy + ch + radius, rows))
    return roi


def _open_slits(roi: NDArray, labeller: _BoxLabeller, doubt: NDArray, region: NDArray, warp: NDArray,
                cfg: SegmentationConfig) -> NDArray:
    """Open thin slits the coarse segmentation closed (a sleeve lying against the body, the
    crotch of pants): too long for the band passes, yet connected to the table outside.

    Full-resolution pixels inside the garment (0/255 `roi`) whose work-size pixel (or a
    neighbour) is in doubt (not sure garment in the trimap, or far from the garment's colour:
    `slit_mahalanobis`) are labelled per pixel; table-labelled ones that are connected to the
    table outside the garment through other table pixels, after an opening that cuts one-pixel
    chains of noise, are removed from the garment. Enclosed table-like blobs stay garment.
    """
    h, w = roi.shape
    doubt = cv2.dilate((doubt & (region > 0)).astype(np.uint8), np.ones((3, 3), np.uint8))
    doubt_full = cv2.warpAffine(doubt * 255, warp, (w, h), flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP,
                                borderMode=cv2.BORDER_CONSTANT)
    labeller.label(cv2.subtract(cv2.bitwise_and(doubt_full, roi), labeller.seen), roi)
    table_like = cv2.bitwise_and(cv2.subtract(labeller.seen, labeller.cloth), roi)
    radius = cfg.slit_min_width_px // 2
    if radius > 0:
        table_like = cv2.morphologyEx(table_like, cv2.MORPH_OPEN, np.ones((2 * radius + 1, 2 * radius + 1),
                                                                          np.uint8))
    # the box is padded beyond the coarse garment, so its border is table
    return cv2.subtract(roi, _reaching_border(cv2.bitwise_or(table_like, cv2.bitwise_not(roi))))
