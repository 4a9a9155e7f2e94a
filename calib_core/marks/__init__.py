"""Sub-pixel detection of circular and cross Marks.

Segmentation finds candidates: the frame is smoothed, a robust quadratic illumination
surface is taken off, and the connected components below (above) a threshold are the
dark (bright) candidates; the threshold is Otsu's unless that splits the background's
noise. Each candidate is refined by fitting an intensity model to the raw pixels by
Levenberg-Marquardt (circles: a compiled solver that sums each dot's normal equations
pixel by pixel, for speed; crosses: scipy.optimize.least_squares). A circular
dot seen at an angle is an ellipse; a blob shaped like one (by its second moments) is
fitted with the ellipse's two shape parameters added, and reported as a circle of its
mean radius. Under
Gaussian noise that fit is the maximum-likelihood estimate, which is what lets the centre
error approach the Cramer-Rao bound. The covariance of the centre comes from the fit's
Jacobian and residual variance.

Pixels follow OpenCV's convention: the centre of the top-left pixel is (0, 0).

Modules: ``config`` (settings and result types), ``segmentation`` (candidates; with
``trend``, the illumination trend's robust fit, ``noise``, the pixel noise's robust
sigma, ``levels``, the masks' threshold levels, and ``labels``, the blobs' labels
painted in their boxes, all compiled),
``intensity`` (the cross's intensity model), ``bands`` (blob moments, edge bands and
starting levels, compiled), ``dot_fit`` (the dot's model and its compiled solver),
``dot_run`` (a frame's dots from window to fit, one compiled run per half of them),
``halves`` (the helper thread that takes the other half), ``circle`` and ``cross`` (the
sub-pixel fits), ``pixels`` (shared helpers), ``detect`` (:func:`detect_marks`),
``precompile`` (fills numba's cache at set-up). numba is imported with the first frame
detected.
"""
from calib_core.marks.config import SHAPES, Detection, DetectorConfig, Mark
from calib_core.marks.detect import detect_marks
from calib_core.marks.segmentation import estimate_noise

__all__ = ['SHAPES', 'Detection', 'DetectorConfig', 'Mark', 'detect_marks', 'estimate_noise']
