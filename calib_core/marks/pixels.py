"""Pixel helpers of the Mark fits: the frame's checks, windows and patches clipped to the
frame, robust levels, saturation checks, and the centre covariance of a fit."""
from __future__ import annotations

import numpy as np

from calib_core.errors import DetectionError, InvalidInputError


def full_scale(image: np.ndarray) -> float | None:
    if image.dtype == np.uint8:
        return 255.0
    if image.dtype == np.uint16:
        return 65535.0
    return None


def read_grey_image(path) -> np.ndarray | None:
    """The image file ``path`` as one grey channel at its own depth (8 or 16 bits, or
    float: a 12-bit camera's frames in 16-bit PNG or TIFF keep their precision; colour is
    weighted to grey as OpenCV does), or None where OpenCV cannot read it."""
    import cv2
    return cv2.imread(str(path), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_ANYDEPTH)


# The pixel types of camera frames, rendered frames and files, which make setup compiles
# the detector for (precompile.py), C-ordered.
PIXEL_TYPES = (np.uint8, np.uint16, np.float32, np.float64)


def check_image(image) -> np.ndarray:
    """The frame as the compiled code reads it: 2-D, finite, in the machine's byte order,
    C-ordered and of one of PIXEL_TYPES (other integer types become float64, exactly).
    Any other layout or type would be compiled anew on its first frame: 3-4 s for a view
    of part of a frame, a Fortran-ordered or an int32 one."""
    image = np.asarray(image)
    if image.ndim != 2:
        raise InvalidInputError(f'expected a single-channel image (2-D array), got shape {image.shape}')
    if image.size == 0:
        raise InvalidInputError('empty image')
    if image.dtype.kind == 'f' and not np.all(np.isfinite(image)):
        raise InvalidInputError('image contains NaN or infinite values')
    if image.dtype.kind not in 'uif':
        raise InvalidInputError(f'unsupported pixel type {image.dtype}')
    if not image.dtype.isnative:
        image = image.astype(image.dtype.newbyteorder('='))
    if image.dtype.type not in PIXEL_TYPES:
        image = image.astype(np.float64)
    return np.ascontiguousarray(image)


def upper_median(values) -> float:
    """The median of a 1-D array of odd size; of even size, the upper of the two middle
    values. For starting values and ring levels, at a tenth of np.median's call cost."""
    middle = values.size // 2
    return float(np.partition(values, middle)[middle])


def outer_ring(patch):
    """The outermost rows and columns of a 2-D patch, as one 1-D array."""
    return np.concatenate([patch[0], patch[-1], patch[:, 0], patch[:, -1]])


def clipped_window(shape, x0, y0, w, h, pad):
    """Rows r0:r1 and columns c0:c1 of the bounding box grown by ``pad``, inside the image;
    of one box (ints) or of many (arrays of the same length, each r0 etc. an array)."""
    height, width = shape
    return (np.maximum(y0 - pad, 0), np.minimum(y0 + h + pad, height),
            np.maximum(x0 - pad, 0), np.minimum(x0 + w + pad, width))


def pixel_patch(pixels, x0, y0, w, h, pad):
    r0, r1, c0, c1 = clipped_window(pixels.shape, x0, y0, w, h, pad)
    vv, uu = np.mgrid[r0:r1, c0:c1]
    return pixels[r0:r1, c0:c1].astype(np.float64), uu.astype(float), vv.astype(float)


def check_saturation(values, full):
    if full is not None and np.mean(values >= full) > 0.01:
        raise DetectionError('saturated Mark (clipped intensities bias the centre)')


def centre_covariances(normals, residual_variances):
    """Centre covariances (k, 2, 2), px^2, from normal matrices J^T J (k, p, p) and the
    fits' residual variances (k,), and which of them are covariances: finite and positive
    definite. Where one is not, the pixels did not determine the centre, whatever the
    fit says."""
    try:
        inverse = np.linalg.inv(normals)
    except np.linalg.LinAlgError:
        inverse = np.linalg.pinv(normals)
    with np.errstate(over='ignore', invalid='ignore'):
        covariances = inverse[:, :2, :2] * residual_variances[:, None, None]
        uu, uv, vv = covariances[:, 0, 0], covariances[:, 0, 1], covariances[:, 1, 1]
        valid = np.isfinite(covariances).all(axis=(1, 2)) & (uu > 0) & (uu * vv - uv * uv > 0)
    return covariances, valid


def residual_variance(residuals, parameters):
    """Residual variance of a fit of ``parameters`` unknowns (image units^2)."""
    return float(residuals @ residuals) / max(residuals.size - parameters, 1)
