"""Fiber cross sections: constructors, validation, file format."""

from __future__ import annotations

import numpy as np
import pytest

from wavebrdf.solver.fiber import (
    CrossSection,
    ShapeError,
    circle,
    ellipse,
    load_shape,
    polygon,
    recommended_segments,
    save_shape,
    spline,
)

SQUARE = [[0.0, 0.0], [0.6, 0.0], [0.6, 0.6], [0.0, 0.6]]


def test_circle_geometry():
    shape = circle(1.0, 300)
    assert shape.segments == 300
    np.testing.assert_allclose(shape.area, np.pi, rtol=1e-14)  # area preserving by default
    inscribed = circle(1.0, 300, preserve_area=False)
    np.testing.assert_allclose(np.hypot(*inscribed.nodes.T), 1.0, rtol=1e-15)
    np.testing.assert_allclose(inscribed.area, 150 * np.sin(2 * np.pi / 300), rtol=1e-14)
    midpoints = shape.nodes + 0.5 * shape.edges
    assert np.all(np.sum(shape.normals * midpoints, axis=1) > 0)  # outward
    np.testing.assert_allclose(shape.width([0.0, 1.0]), 2.0, rtol=1e-4)


def test_ellipse_is_counter_clockwise_uniform_and_area_preserving():
    shape = ellipse(0.4, 0.25, 64)
    assert shape.area > 0
    assert np.std(shape.lengths) / np.mean(shape.lengths) < 1e-2
    np.testing.assert_allclose(shape.area, np.pi * 0.4 * 0.25, rtol=1e-5)
    on_curve = ellipse(0.4, 0.25, 64, preserve_area=False)
    np.testing.assert_allclose((on_curve.nodes[:, 0] / 0.4) ** 2 + (on_curve.nodes[:, 1] / 0.25) ** 2, 1.0, rtol=1e-12)
    np.testing.assert_allclose(shape.width([0.0, np.pi / 2]), [0.5, 0.8], rtol=2e-3)  # seen from +x: 2b


@pytest.mark.parametrize("segments", [128, 256, 512])
def test_a_thin_ellipse_keeps_its_tips(segments):
    """Aspect 100 (1 × 0.01 µm): the element (≈ 4 µm / N) is far longer than the tip's radius of
    curvature b²/a = 10⁻⁴ µm, where the area-preserving move κΔ²/12 would carry the tip node
    outward by up to 0.8 µm (tip at 1.81 µm for N = 128). Every node stays within Δ/12 of the
    ellipse (distance along the normal ≈ (F − 1)/|∇F| with F = (x/a)² + (y/b)²), the tips at
    1 µm to Δ/12, and the area is πab to 0.2 %."""
    a, b = 1.0, 0.01
    shape = ellipse(a, b, segments)
    step = float(np.mean(shape.lengths))
    x, y = shape.nodes.T
    level = (x / a) ** 2 + (y / b) ** 2
    gradient = 2.0 * np.hypot(x / a**2, y / b**2)
    assert np.max(np.abs(level - 1.0) / gradient) <= step / 12 * 1.01
    assert abs(np.max(np.abs(x)) - a) <= step / 12
    np.testing.assert_allclose(shape.area, np.pi * a * b, rtol=2e-3)


def test_polygon_corners_kept_and_graded():
    plain = polygon(SQUARE)
    assert plain.segments == 4
    uniform = polygon(SQUARE, 40)
    assert uniform.segments == 40
    np.testing.assert_allclose(uniform.lengths, 0.06, rtol=1e-12)
    graded = polygon(SQUARE, 40, corner_grading=2)
    corners = [np.flatnonzero(np.all(np.isclose(graded.nodes, c), axis=1)) for c in SQUARE]
    assert all(len(c) == 1 for c in corners)
    assert graded.lengths.min() == pytest.approx(0.06 / 4)
    assert graded.segments == 40 + 4 * 2 * 2
    np.testing.assert_allclose(graded.area, 0.36, rtol=1e-12)


def test_clockwise_points_are_reversed():
    cw = polygon(SQUARE[::-1])
    assert cw.area == pytest.approx(0.36)


def test_spline_through_points():
    t = 2 * np.pi * np.arange(16) / 16
    shape = spline(np.c_[np.cos(t), 0.5 * np.sin(t)], 80)
    assert shape.segments == 80
    np.testing.assert_allclose(shape.area, np.pi * 0.5, rtol=2e-3)


@pytest.mark.parametrize(
    "points, message",
    [
        ([[0, 0], [3, 0], [3, 1], [1, -1], [0, 2]], "intersects itself"),
        ([[0, 0], [1, 0], [1, 0], [0, 1]], "coincide"),
        ([[0, 0], [1, 1], [2, 2]], "zero area"),
        ([[0, 0], [1, 0]], "at least 3"),
        ([[0, 0], [1, np.nan], [0, 1]], "NaN"),
        ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], "shape"),
    ],
)
def test_invalid_polygons_are_rejected(points, message):
    with pytest.raises(ShapeError, match=message):
        polygon(points)


def test_cross_section_requires_counter_clockwise():
    with pytest.raises(ShapeError, match="counter-clockwise"):
        CrossSection(np.array(SQUARE[::-1]))


@pytest.mark.parametrize("call, message", [
    (lambda: circle(-1.0, 10), "radius_um"),
    (lambda: circle(1.0, 2), "segments"),
    (lambda: ellipse(0.4, 0.0, 10), r"semi_axes_um\[1\]"),
    (lambda: polygon(SQUARE, 40, corner_grading=-1), "corner_grading"),
    (lambda: polygon(SQUARE, 3), "segments"),
])
def test_bad_parameters_name_themselves(call, message):
    with pytest.raises(ShapeError, match=message):
        call()


def test_shape_file_round_trip(tmp_path):
    path = save_shape(tmp_path / "square.txt", SQUARE, segments=40, corner_grading=1)
    shape = load_shape(path)
    np.testing.assert_allclose(shape.nodes, polygon(SQUARE, 40, corner_grading=1).nodes)
    assert shape.name == "square"
    csv = tmp_path / "tri.csv"
    csv.write_text("# interpolation = spline\n# segments = 30\n0, 0\n1, 0  # comment\n\n0.5, 0.8\n")
    assert load_shape(csv).segments == 30
    assert load_shape(csv, segments=12).segments == 12


def test_shape_file_errors_name_line(tmp_path):
    bad = tmp_path / "bad.txt"
    bad.write_text("0 0\n1 0 3\n0 1\n")
    with pytest.raises(ShapeError, match="bad.txt:2"):
        load_shape(bad)
    with pytest.raises(ShapeError, match="does not exist"):
        load_shape(tmp_path / "missing.txt")
    spl = tmp_path / "spl.txt"
    spl.write_text("# interpolation = spline\n0 0\n1 0\n0 1\n")
    with pytest.raises(ShapeError, match="segments"):
        load_shape(spl)


def test_recommended_segments_follows_the_papers_mesh():
    """[P]: 300 segments for a 1 µm circle at 0.4 µm with m = 1.55 (about 12 per interior λ)."""
    n = recommended_segments(circle(1.0, 64), 0.4, 1.55)
    assert 280 <= n <= 300
    assert recommended_segments(circle(1.0, 64), 0.4, 1.55 - 3j) > 2 * n  # absorbing: shorter λ/|m|
