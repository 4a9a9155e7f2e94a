"""The renderer's ellipse coverage (calib_core/sim/render.py), on which every simulated
camera frame rests: at equal axes it agrees with the circle's exact form (non-central
chi-square) to 2e-6 of the contrast over radius 3-80 px and blur 0.05-1.5 px, and the
48-node quadrature used where the blur is not much narrower than the ellipse stays within
1e-6 of the 96-node one; the circle's tabulated radial profile stays within 1e-6 of the
exact CDF at every distance. The rendering through the pixel's box conserves the Mark's
light, and at 1 px blur, where the blur hides the box's shape, agrees with the fold of the
box into the Gaussian."""
import numpy as np
import pytest
from scipy.stats import ncx2

import calib_core.sim.render as render
from calib_core.marks.intensity import edge_sigma

TOLERANCE = {'against_exact_circle': 2e-6, 'coarse_against_fine': 1e-6,
             'profile_against_exact': 1e-6, 'box_light': 1e-6, 'box_against_fold': 5e-4}


def _points(rng, major, minor, sigma, n=4000):
    reach = 6 * sigma + 2
    return (rng.uniform(-major - reach, major + reach, n),
            rng.uniform(-minor - reach, minor + reach, n))


@pytest.mark.parametrize('radius', [3.0, 10.0, 24.0, 80.0])
@pytest.mark.parametrize('blur', [0.05, 0.3, 0.8, 1.5])
def test_equal_axes_agree_with_the_exact_circle(radius, blur):
    rng = np.random.default_rng(int(radius * 10 + blur * 100))
    sigma = float(edge_sigma(blur))
    x, y = _points(rng, radius, radius, sigma)
    exact = ncx2.cdf((radius / sigma) ** 2, 2, (x ** 2 + y ** 2) / sigma ** 2)
    quadrature = render.ellipse_coverage(x, y, radius, radius, sigma)
    assert np.abs(quadrature - exact).max() < TOLERANCE['against_exact_circle']


@pytest.mark.parametrize('radius', [3.0, 10.0, 24.0, 80.0])
@pytest.mark.parametrize('aspect', [1.0, 1.3, 3.0])
def test_the_coarse_quadrature_where_it_is_used_matches_the_fine_one(radius, aspect,
                                                                     monkeypatch):
    rng = np.random.default_rng(int(radius * 10 + aspect * 7))
    major, minor = radius * np.sqrt(aspect), radius / np.sqrt(aspect)
    for blur in (0.05, 0.3, 0.8, 1.0, 1.5):
        sigma = float(edge_sigma(blur))
        if sigma < render.COARSE_ABOVE * major:
            continue                      # the fine quadrature is used: nothing to compare
        x, y = _points(rng, major, minor, sigma)
        coarse = render.ellipse_coverage(x, y, major, minor, sigma)
        monkeypatch.setattr(render, '_CHORD_NODES_COARSE', render._CHORD_NODES)
        fine = render.ellipse_coverage(x, y, major, minor, sigma)
        monkeypatch.undo()
        assert np.abs(coarse - fine).max() < TOLERANCE['coarse_against_fine'], (blur, sigma)


@pytest.mark.parametrize('radius', [0.5, 3.0, 10.0, 24.0, 80.0])
@pytest.mark.parametrize('blur', [0.0, 0.3, 1.5, 4.0])
def test_the_circles_tabulated_profile_matches_the_exact_cdf(radius, blur):
    rng = np.random.default_rng(int(radius * 10 + blur * 100))
    sigma = float(edge_sigma(blur))
    x, y = _points(rng, radius, radius, sigma, n=20000)
    x[:3], y[:3] = 0.0, (0.0, radius, 1e4)               # the centre, the edge, far away
    exact = ncx2.cdf((radius / sigma) ** 2, 2, (x ** 2 + y ** 2) / sigma ** 2)
    tabulated = render.coverage(render.MarkShape('circle', 0.0, 0.0, radius), x, y, blur)
    assert np.abs(tabulated - exact).max() < TOLERANCE['profile_against_exact']


@pytest.mark.parametrize('blur', [0.0, 0.4, 1.0])
@pytest.mark.parametrize('aspect', [1.0, 1.8])
def test_rendering_through_the_box_keeps_the_light(blur, aspect):
    """A disk and an ellipse (mean radius 10 px) through the box and the blur: the frame
    holds the Mark's area times its contrast (relative 1e-6), and at 1 px blur each pixel
    is within 5e-4 of the contrast of the fold into the Gaussian."""
    mark = render.MarkShape('circle', 40.3, 39.6, 10.0, angle=0.7, aspect=aspect)
    boxed = render.render_through_box([mark], 80, 80, blur, 0.0, 1.0)
    assert abs(boxed.sum() / (np.pi * 100.0) - 1) < TOLERANCE['box_light']
    if blur == 1.0:
        folded = render.render([mark], 80, 80, blur, 0.0, 1.0)
        assert np.max(np.abs(boxed - folded)) < TOLERANCE['box_against_fold']
