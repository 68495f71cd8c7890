"""Table colour model: a GMM of RGB triples (paper Sec. III-A) with an illumination gain map.

The GMM's components are initialised by the binary-split palette algorithm (repeatedly split
the cluster with the largest variance along its principal direction, at its mean) and fitted by
EM (maximum likelihood), written in numpy (OpenCV 5 has no `cv2.ml`; numpy EM on a few tens of
thousands of sampled pixels takes milliseconds, so no extra dependency is needed).

Uneven light: the cell's lamps and camera are fixed, so the table's brightness field (bright
centre, darker corners) is the same in every image. Fitting learns it as a coarse `gain` grid:
the mean luminance of the table pixels in each cell divided by the overall mean, smoothed. Before
the GMM sees a pixel, its RGB is divided by the gain interpolated at its position, so the GMM
models the table's colour under flat light and does not need extra components (or a loose
likelihood threshold) to cover the dark corners.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from .annotations import Annotation
from .errors import ImageError, ModelError

_LOG_2PI = float(np.log(2 * np.pi))


@dataclass(frozen=True)
class TableModel:
    weights: NDArray      # (K,)
    means: NDArray        # (K, 3) BGR, gain-normalised
    covariances: NDArray  # (K, 3, 3)
    threshold_fg: float   # log-likelihood P_F: below it a pixel is surely garment
    threshold_bg: float   # log-likelihood P_B: above it a pixel is surely table
    gain: NDArray         # (rows, cols) relative table brightness over the image

    @cached_property
    def terms(self) -> GaussianTerms:
        """The GMM as per-pixel labelling needs it, computed on first use."""
        return GaussianTerms.of(self.weights, self.means, self.covariances)

    def to_dict(self) -> dict[str, Any]:
        return {
            "weights": [float(w) for w in self.weights],
            "means": [[float(v) for v in m] for m in self.means],
            "covariances": [[[float(v) for v in row] for row in c] for c in self.covariances],
            "threshold_fg": float(self.threshold_fg),
            "threshold_bg": float(self.threshold_bg),
            "gain": [[round(float(v), 5) for v in row] for row in self.gain],
        }


def table_model_from_fields(fields: Any) -> TableModel:
    """From a `drivers.common.configfile.Fields` mapping (see `TableModel.to_dict`); a `provenance`
    mapping (what data, seed, date and command made the file) is for readers and is not used."""
    fields.reject_unknown({"weights", "means", "covariances", "threshold_fg", "threshold_bg", "gain",
                           "provenance"})
    w = np.asarray(fields.floats("weights"))
    k = len(w)
    means_raw = fields.raw("means")
    cov_raw = fields.raw("covariances")
    gain_raw = fields.raw("gain")
    try:
        means = np.asarray(means_raw, float)
        covs = np.asarray(cov_raw, float)
        gain = np.asarray(gain_raw, float)
    except (TypeError, ValueError) as exc:
        raise fields.error("means", f"must be numeric arrays: {exc}") from exc
    if means.shape != (k, 3):
        raise fields.error("means", f"must be {k} RGB triples, got shape {means.shape}")
    if covs.shape != (k, 3, 3):
        raise fields.error("covariances", f"must be {k} 3x3 matrices, got shape {covs.shape}")
    if np.any(np.linalg.eigvalsh(covs) <= 0):
        raise fields.error("covariances", "must be positive definite")
    if gain.ndim != 2 or min(gain.shape) < 1 or np.any(gain <= 0):
        raise fields.error("gain", "must be a non-empty grid of positive numbers")
    if k < 1 or np.any(w <= 0):
        raise fields.error("weights", "must be positive")
    fg, bg = fields.float("threshold_fg"), fields.float("threshold_bg")
    if fg > bg:
        raise fields.error("threshold_fg", f"must be <= threshold_bg ({bg}), got {fg}")
    return TableModel(w / w.sum(), means, covs, fg, bg, gain)


@dataclass(frozen=True)
class GaussianTerms:
    """A GMM in the form per-pixel likelihoods need, computed once: per component the whitening
    matrix (transposed inverse Cholesky factor), the mean, and log weight minus log normaliser."""

    whitening: NDArray   # (K, 3, 3)
    means: NDArray       # (K, 3)
    constants: NDArray   # (K,)

    @classmethod
    def of(cls, weights: NDArray, means: NDArray, covs: NDArray) -> GaussianTerms:
        chol = np.linalg.cholesky(np.asarray(covs, float))
        whitening = np.transpose(np.linalg.inv(chol), (0, 2, 1))
        logdet = 2.0 * np.log(np.diagonal(chol, axis1=1, axis2=2)).sum(axis=1)
        constants = np.log(np.asarray(weights, float)) - 0.5 * (3 * _LOG_2PI + logdet)
        return cls(whitening, np.asarray(means, float), constants)

    def log_likelihood(self, x: NDArray, exact: bool = False) -> NDArray:
        """log p(x) for x of shape (n, 3) (float32 arithmetic for many x unless `exact`)."""
        return _logsumexp(self.component_log(x, exact), axis=1)

    def component_log(self, x: NDArray, exact: bool = False) -> NDArray:
        """(n, K) log weight_k + log N(x; mean_k, cov_k).

        Per-image pixel labelling uses float32 (the thresholds are compared with a margin far above
        its rounding) in two OpenCV channel transforms: every component's whitened offsets at once,
        then, squared, their weighted sums with the constants. Fitting (`exact`) and small inputs
        use float64 with element-wise products: a BLAS matmul starts OpenBLAS threads, which on a
        busy 2-core machine cost more than the product itself.
        """
        if len(x) > 4096 and not exact:
            z = cv2.transform(np.ascontiguousarray(x, np.float32).reshape(-1, 1, 3), self._whiten_affine)
            cv2.multiply(z, z, dst=z)
            return cv2.transform(z, self._sum_affine).reshape(len(x), -1)
        xx = np.asarray(x, np.float64)
        out = np.empty((len(x), len(self.constants)), np.float64)
        for c, constant in enumerate(self.constants):
            inv = self.whitening[c]
            d = xx - self.means[c]
            # the whitening is upper triangular: z_j = sum over i <= j of d_i inv[i, j]
            z0 = d[:, 0] * inv[0, 0]
            z1 = d[:, 0] * inv[0, 1] + d[:, 1] * inv[1, 1]
            z2 = d[:, 0] * inv[0, 2] + d[:, 1] * inv[1, 2] + d[:, 2] * inv[2, 2]
            out[:, c] = constant - 0.5 * (z0 * z0 + z1 * z1 + z2 * z2)
        return out

    @cached_property
    def _whiten_affine(self) -> NDArray:
        """(3K, 4) float32: x -> every component's whitened offset W_k^T (x - mean_k)."""
        k = len(self.constants)
        affine = np.zeros((3 * k, 4))
        for c in range(k):
            affine[3 * c:3 * c + 3, :3] = self.whitening[c].T
            affine[3 * c:3 * c + 3, 3] = -self.whitening[c].T @ self.means[c]
        return affine.astype(np.float32)

    @cached_property
    def _sum_affine(self) -> NDArray:
        """(K, 3K + 1) float32: squared whitened offsets -> constant_k - half their sum."""
        k = len(self.constants)
        affine = np.zeros((k, 3 * k + 1))
        for c in range(k):
            affine[c, 3 * c:3 * c + 3] = -0.5
            affine[c, 3 * k] = self.constants[c]
        return affine.astype(np.float32)


def gaussian_log_likelihood(x: NDArray, weights: NDArray, means: NDArray, covs: NDArray,
                            exact: bool = False) -> NDArray:
    """log p(x) under the GMM for x of shape (n, 3) (float32 arithmetic for many x unless `exact`)."""
    return GaussianTerms.of(weights, means, covs).log_likelihood(x, exact)



def mahalanobis2(x: NDArray, mean: NDArray, cov: NDArray) -> NDArray:
    """Squared Mahalanobis distances of (n, 3) x, in float32 with element-wise products."""
    inv = np.linalg.inv(np.linalg.cholesky(cov)).T.astype(np.float32)
    d = np.asarray(x, np.float32) - np.asarray(mean, np.float32)
    m2 = np.zeros(len(d), np.float32)
    for j in range(3):
        zj = d[:, 0] * inv[0, j] + d[:, 1] * inv[1, j] + d[:, 2] * inv[2, j]
        m2 += zj * zj
    return m2


def _logsumexp(a: NDArray, axis: int) -> NDArray:
    if a.ndim == 2 and axis == 1 and a.shape[1] <= 8:
        # few components: column-wise maxima and sums (numpy reduces a short last axis slowly)
        cols = [a[:, k] for k in range(a.shape[1])]
        largest = cols[0].copy()
        for c in cols[1:]:
            np.maximum(largest, c, out=largest)
        acc = np.zeros_like(largest)
        for c in cols:
            acc += np.exp(c - largest)
        out = largest + np.log(acc)
    else:
        mk = a.max(axis=axis, keepdims=True)
        out = (mk + np.log(np.exp(a - mk).sum(axis=axis, keepdims=True))).squeeze(axis)
    return out.astype(np.float64) if out.dtype != np.float64 else out


def covariance(x: NDArray) -> NDArray:
    """Sample covariance (ddof 1) of (n, 3) points without BLAS (see `_component_log`)."""
    x = np.asarray(x, np.float64)
    d = x - x.mean(axis=0)
    out = np.empty((3, 3))
    for i in range(3):
        for j in range(i, 3):
            out[i, j] = out[j, i] = float((d[:, i] * d[:, j]).sum())
    return out / max(len(x) - 1, 1)


def binary_split_init(x: NDArray, k: int) -> NDArray:
    """Palette-design binary split: labels (n,) in 0..k-1."""
    labels = np.zeros(len(x), int)
    for new in range(1, k):
        # split the cluster with the largest total variance along its principal axis
        best, best_var = -1, -1.0
        for c in range(new):
            pts = x[labels == c]
            if len(pts) < 2:
                continue
            v = float(np.trace(covariance(pts)) * len(pts))
            if v > best_var:
                best, best_var = c, v
        if best < 0:
            break
        sel = np.flatnonzero(labels == best)
        pts = x[sel]
        _, evecs = np.linalg.eigh(covariance(pts))
        axis = evecs[:, -1]
        d = pts - pts.mean(axis=0)
        proj = d[:, 0] * axis[0] + d[:, 1] * axis[1] + d[:, 2] * axis[2]
        labels[sel[proj > 0]] = new
    return labels


def fit_gmm(x: NDArray, k: int, iterations: int, reg: float, tol: float = 1e-6, trim: float = 0.0
            ) -> tuple[NDArray, NDArray, NDArray]:
    """Maximum-likelihood GMM by EM from the binary-split initialisation.

    `trim` > 0: trimmed likelihood; every M-step uses all but this least likely part of `x`, so a
    few pixels of something else (garment past an annotation's margin, near the border of an image)
    do not widen the components or draw one of their own.
    """
    x = np.asarray(x, float)
    if len(x) < 10 * k:
        raise ModelError(f"too few table pixels to fit a {k}-component colour model: {len(x)}")
    labels = binary_split_init(x, k)
    resp = np.zeros((len(x), k))
    resp[np.arange(len(x)), labels] = 1.0
    kept = np.ones(len(x), bool)
    trimmed = min(int(trim * len(x)), len(x) - 10 * k)
    prev = -np.inf
    eye = np.eye(3) * reg
    for _ in range(iterations):
        used, used_resp = x[kept], resp[kept]
        nk = used_resp.sum(axis=0) + 1e-12
        weights = nk / nk.sum()
        means = (used_resp.T @ used) / nk[:, None]
        covs = np.empty((k, 3, 3))
        for c in range(k):
            d = used - means[c]
            covs[c] = (used_resp[:, c, None] * d).T @ d / nk[c] + eye
        comp = GaussianTerms.of(weights, means, covs).component_log(x, exact=True)
        log_density = _logsumexp(comp, axis=1)
        resp = np.exp(comp - log_density[:, None])
        if trimmed > 0:
            kept = log_density > np.partition(log_density, trimmed - 1)[trimmed - 1]
        mean_ll = float(log_density[kept].mean())
        if mean_ll - prev < tol:
            break
        prev = mean_ll
    return weights, means, covs


def luminance(img: NDArray) -> NDArray:
    return img.astype(np.float32).mean(axis=2)


def gain_field(gain: NDArray, shape: tuple[int, int]) -> NDArray:
    """The gain grid interpolated to an image of `shape` (rows, cols)."""
    return cv2.resize(np.asarray(gain, np.float32), (shape[1], shape[0]), interpolation=cv2.INTER_LINEAR)


def normalise(img: NDArray, gain: NDArray) -> NDArray:
    """BGR pixels divided by the table's brightness field: (rows, cols, 3) float32."""
    return img.astype(np.float32) / gain_field(gain, img.shape[:2])[..., None]


def check_image(img: Any, name: str = "image") -> NDArray:
    if not isinstance(img, np.ndarray) or img.size == 0:
        raise ImageError(f"{name}: empty or not an image array")
    if img.ndim != 3 or img.shape[2] != 3:
        raise ImageError(f"{name}: must be a colour (rows, cols, 3) image, got shape {img.shape}")
    if img.dtype != np.uint8:
        raise ImageError(f"{name}: must be 8-bit, got {img.dtype}")
    return img


def fit_table_model(images: Sequence[NDArray], masks: Sequence[NDArray | None] | None = None,
                    config: Any = None, seed: int = 0, fit: Any = None) -> TableModel:
    """Learn the table model from images; masks (True = table pixel, any size) select pixels, None = all.

    `config` is a `PerceptionConfig` (segmentation working size, quantiles); None uses its
    defaults. `fit` is a `TableFitConfig` (components, EM, samples, trimming, outliers, gain grid),
    by default `config.table`. Images already at the working size are used as they are.

    With `fit.outlier_mahalanobis` > 0 the model is fitted twice: the second time without the
    pixels the first fit does not explain as table (`_typical`: garment that leaked past a mask's
    margin, a curved hem between two annotated corners, a fold's edge), so they neither widen the
    colour model nor darken the brightness field.
    """
    if config is None:
        from .config import PerceptionConfig
        config = PerceptionConfig()
    fit = fit or config.table
    if not images:
        raise ModelError("no images to fit the table model")
    w, h = config.segmentation.work_size
    small_imgs, small_masks = [], []
    for index, img in enumerate(images):
        check_image(img, f"image {index}")
        small = img if img.shape[:2] == (h, w) else cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
        mask = None if masks is None else masks[index]
        if mask is None:
            small_mask = np.ones((h, w), bool)
        else:
            small_mask = cv2.resize(np.asarray(mask, np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0
        small_imgs.append(small)
        small_masks.append(small_mask)
    model = _fit_masked(small_imgs, small_masks, config.segmentation, fit, seed)
    if fit.outlier_mahalanobis > 0:
        limit = fit.outlier_mahalanobis ** 2
        small_masks = [mask & _typical(img, model, limit, fit.foreign_weight)
                       for img, mask in zip(small_imgs, small_masks, strict=True)]
        model = _fit_masked(small_imgs, small_masks, config.segmentation, fit, seed)
    return model


def _typical(img: NDArray, model: TableModel, limit2: float, foreign_weight: float) -> NDArray:
    """The pixels of `img` the model explains as table: within squared Mahalanobis distance
    `limit2` of a component, and that component not a foreign one. A component lighter than
    `foreign_weight` whose colour, at any brightness, lies that far from every other component is
    something else that leaked into the pixels in bulk (a dark garment's strip draws a component
    of its own, so no per-pixel distance rejects it); the table's darker grain and seams share its
    hue and stay."""
    k = len(model.weights)
    foreign = []
    for c in range(k):
        others = [o for o in range(k) if o != c]
        if model.weights[c] < foreign_weight and others:
            distance2, _ = ray_mahalanobis2(model.means[c][None], model.weights[others], model.means[others],
                                            model.covariances[others])
            foreign.append(bool(distance2[0] > limit2))
        else:
            foreign.append(False)
    colours = normalise(img, model.gain).reshape(-1, 3)
    distances = np.stack([mahalanobis2(colours, mean, cov)
                          for mean, cov in zip(model.means, model.covariances, strict=True)], axis=1)
    nearest = np.argmin(distances, axis=1)
    typical = (distances[np.arange(len(colours)), nearest] <= limit2) & ~np.asarray(foreign)[nearest]
    return typical.reshape(img.shape[:2])


def _fit_masked(small_imgs: Sequence[NDArray], small_masks: Sequence[NDArray], seg: Any, fit: Any,
                seed: int) -> TableModel:
    """The model of the masked pixels of working-size images."""
    rows, cols = fit.gain_grid
    rng = np.random.default_rng(seed)
    # brightness field: masked cell means of luminance, pooled over images
    brightness_sum = np.zeros((rows, cols))
    coverage = np.zeros((rows, cols))
    for img, mask in zip(small_imgs, small_masks, strict=True):
        brightness_sum += cv2.resize(luminance(img) * mask, (cols, rows), interpolation=cv2.INTER_AREA)
        coverage += cv2.resize(mask.astype(np.float32), (cols, rows), interpolation=cv2.INTER_AREA)
    valid = coverage > fit.min_cell_coverage
    if not valid.any():
        raise ModelError("no table pixels in the training images")
    gain = _fill_cells(np.where(valid, brightness_sum / np.maximum(coverage, 1e-9), np.nan))
    gain = cv2.GaussianBlur(gain.astype(np.float32), (3, 3), 0)
    gain = gain / float(np.mean(gain))
    samples = []
    per_image = max(fit.samples // len(small_imgs), 1)
    for img, mask in zip(small_imgs, small_masks, strict=True):
        colours = normalise(img, gain)[mask]
        if len(colours) > per_image:
            colours = colours[rng.choice(len(colours), per_image, replace=False)]
        samples.append(colours)
    x = np.concatenate(samples).astype(float)
    weights, means, covs = fit_gmm(x, fit.components, fit.em_iterations, fit.covariance_floor,
                                   trim=fit.trim_fraction)
    log_likelihood = gaussian_log_likelihood(x, weights, means, covs, exact=True)
    threshold_fg = float(np.quantile(log_likelihood, seg.quantile_fg))
    threshold_bg = float(np.quantile(log_likelihood, 1.0 - seg.fraction_bg))
    return TableModel(weights, means, covs, threshold_fg, threshold_bg, gain.astype(float))


def annotation_table_mask(annotation: Annotation, shape: tuple[int, int], fit: Any) -> NDArray:
    """The pixels (True) of an annotated image of `shape` (rows, cols) that may be used as table.

    A flat or wrinkled garment's nodes are its outline: the pixels off that polygon grown by
    `fit.annotation_margin_px`. A folded garment's are not (`shape: folded`, or any `fold_<k>` node):
    its fold-line ends and corners carried on top of it, drawn in order, cross and leave parts of
    the garment out; so the pixels off the convex hull of all its nodes grown by
    `fit.folded_margin_px` (every corner of a folded garment is a landmark or a fold-line end).
    """
    points = np.round(annotation.polygon).astype(np.int32)
    garment: NDArray = np.zeros(shape, np.uint8)
    if annotation.shape == "folded" or len(annotation.landmarks) != len(annotation.nodes):
        cv2.fillConvexPoly(garment, cv2.convexHull(points), 1)
        margin = fit.folded_margin_px
    else:
        cv2.fillPoly(garment, [points], 1)
        margin = fit.annotation_margin_px
    if margin > 0:
        disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin + 1, 2 * margin + 1))
        garment = cv2.dilate(garment, disc)
    return garment == 0


def _fill_cells(grid: NDArray) -> NDArray:
    """Fill the cells without table pixels (NaN): by a quadratic surface of log brightness fitted
    to the others when they surround the gap (the light falls off smoothly; a garment or a
    border ring leaves the middle unmeasured), bounded by half and twice their range; else by
    the nearest filled cell."""
    out = grid.copy()
    bad = np.isnan(out)
    if not bad.any():
        return out
    rows, cols = out.shape
    yy, xx = np.nonzero(~bad)
    if len(np.unique(yy)) >= 3 and len(np.unique(xx)) >= 3:
        def terms(r: NDArray, c: NDArray) -> NDArray:
            u, v = (c + 0.5) / cols, (r + 0.5) / rows
            return np.stack([np.ones_like(u), u, v, u * u, u * v, v * v], axis=-1)
        known = out[yy, xx]
        coeffs, *_ = np.linalg.lstsq(terms(yy, xx), np.log(known), rcond=None)
        missing_rows, missing_cols = np.nonzero(bad)
        filled = np.exp(terms(missing_rows, missing_cols) @ coeffs)
        out[missing_rows, missing_cols] = np.clip(filled, 0.5 * known.min(), 2.0 * known.max())
        return out
    for r, c in zip(*np.nonzero(bad), strict=True):
        j = int(np.argmin((yy - r) ** 2 + (xx - c) ** 2))
        out[r, c] = out[yy[j], xx[j]]
    return out


def ray_mahalanobis2(x: NDArray, weights: NDArray, means: NDArray, covs: NDArray
                     ) -> tuple[NDArray, NDArray]:
    """For (n, 3) colours x: the squared Mahalanobis distance of the ray {x / s, s > 0} from the
    nearest GMM component's mean (the table colour at the best brightness), and that brightness
    s (x = s * table colour); float32, element-wise products.

    Light scales a pixel's colour; this distance ignores the scale yet keeps the full 3-D colour
    statistics (a wood-coloured cloth differs from wood across the brightness direction, in which
    the table's components are thin), which a chromaticity distance measures poorly.
    """
    xx = np.asarray(x, np.float32)
    best = np.full(len(xx), np.inf, np.float32)
    scale = np.ones(len(xx), np.float32)
    for c in range(len(weights)):
        prec = np.linalg.inv(covs[c]).astype(np.float32)
        mu = np.asarray(means[c], np.float32)
        pmu = prec @ mu
        px = [xx[:, 0] * prec[0, j] + xx[:, 1] * prec[1, j] + xx[:, 2] * prec[2, j] for j in range(3)]
        a = xx[:, 0] * px[0] + xx[:, 1] * px[1] + xx[:, 2] * px[2]
        b = xx[:, 0] * pmu[0] + xx[:, 1] * pmu[1] + xx[:, 2] * pmu[2]
        cc = np.float32(mu @ pmu)
        ok = (a > 0) & (b > 0)
        m2 = np.where(ok, cc - b * b / np.where(ok, a, 1), np.inf).astype(np.float32)
        better = m2 < best
        best = np.where(better, m2, best)
        scale = np.where(better, a / np.where(ok, b, 1), scale)
    return np.maximum(best, 0), scale
