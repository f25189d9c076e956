"""Formation shape generators and placement: counts, even spacing, frames."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.distance import pdist

from groundctl.show import shapes
from groundctl.show.shapes.font import GLYPH_ROWS


def gaps(points: np.ndarray, closed: bool) -> np.ndarray:
    """Distances between consecutive points (and last -> first if closed)."""
    pts = np.vstack([points, points[:1]]) if closed else points
    return np.linalg.norm(np.diff(pts, axis=0), axis=1)


@pytest.mark.parametrize("fn", [shapes.line, shapes.circle, shapes.square, shapes.star,
                                shapes.spiral, shapes.sphere])
@pytest.mark.parametrize("count", [1, 7, 25, 64])
def test_count_based_shapes_give_count_points(fn, count):
    pts = fn(count, 10.0)
    assert pts.shape == (count, 3 if fn is shapes.sphere else 2)
    assert np.all(np.isfinite(pts))


def test_circle_is_even_and_has_the_right_diameter():
    pts = shapes.circle(25, 12.0)
    np.testing.assert_allclose(np.linalg.norm(pts, axis=1), 6.0)
    g = gaps(pts, closed=True)
    np.testing.assert_allclose(g, g[0])
    assert pdist(pts).min() == pytest.approx(g[0])
    np.testing.assert_allclose(pts[0], [0.0, 6.0], atol=1e-12)  # first slot at the top


def test_square_points_are_on_the_perimeter_evenly_with_the_corners():
    pts = shapes.square(24, 10.0)
    assert np.allclose(np.abs(pts).max(axis=1), 5.0)
    np.testing.assert_allclose(gaps(pts, closed=True), 40.0 / 24)
    corners = {(-5.0, 5.0), (5.0, 5.0), (5.0, -5.0), (-5.0, -5.0)}
    assert corners <= {tuple(p) for p in np.round(pts, 9) + 0.0}


def test_star_spacing_is_even_along_the_outline_and_every_tip_is_a_slot():
    size, arms, inner, count = 20.0, 5, 0.4, 25
    pts = shapes.star(count, size, arms, inner)
    tips = shapes.star_outline(arms, size, inner)[::2]
    for tip in tips:
        assert np.min(np.linalg.norm(pts - tip, axis=1)) < 1e-9
    outline = shapes.star_outline(arms, size, inner)
    edge = np.linalg.norm(outline[1] - outline[0])
    arc = 2 * edge * arms / count
    # Consecutive slots on one edge are exactly one arc step apart.
    g = gaps(pts, closed=True)
    assert g.max() == pytest.approx(arc)
    # Even a notch between two slots keeps them well apart.
    assert pdist(pts).min() > 0.45 * arc


def test_star_with_a_count_not_divisible_by_arms_still_has_distinct_slots():
    pts = shapes.star(64, 46.0)
    assert pdist(pts).min() == pytest.approx(1.66, abs=0.01)


def test_spiral_is_even_along_its_arc_not_its_angle():
    pts = shapes.spiral(40, 20.0, turns=2)
    g = gaps(pts, closed=False)
    # Chords of equal arcs: equal to within the curvature's effect (< 2 %).
    assert g.max() / g.min() < 1.02
    r = np.linalg.norm(pts, axis=1)
    assert r.max() == pytest.approx(10.0)
    assert r.min() == pytest.approx(10.0 / 3)  # starts one arm gap out, not at the centre
    assert pdist(pts).min() > 0.95 * g.min()


def test_sphere_points_are_on_the_sphere_and_spread():
    pts = shapes.sphere(64, 20.0)
    np.testing.assert_allclose(np.linalg.norm(pts, axis=1), 10.0)
    np.testing.assert_allclose(pts.mean(axis=0), 0.0, atol=0.3)
    mean_spacing = np.sqrt(4 * np.pi * 10.0**2 / 64)
    assert pdist(pts).min() > 0.8 * mean_spacing


def test_grid_is_centred_and_spaced_with_a_centred_partial_row():
    pts = shapes.grid(10, 2.0)  # 4 columns: rows of 4, 4, 2
    assert pts.shape == (10, 2)
    assert pdist(pts).min() == pytest.approx(2.0)
    np.testing.assert_allclose(pts[:4, 1], 2.0)
    np.testing.assert_allclose(pts[:4, 0], [-3.0, -1.0, 1.0, 3.0])
    np.testing.assert_allclose(pts[8:, 0], [-1.0, 1.0])
    assert shapes.grid_shape(10) == (3, 4)
    assert shapes.grid_shape(64) == (8, 8)
    assert shapes.grid_shape(10, 5) == (2, 5)


def test_line_runs_along_u_over_its_size():
    pts = shapes.line(5, 8.0)
    np.testing.assert_allclose(pts[:, 0], [-4, -2, 0, 2, 4])
    np.testing.assert_allclose(pts[:, 1], 0.0)


def test_text_dot_counts_spacing_and_centre():
    assert shapes.text_dot_count("HI") == 28
    assert shapes.text_dot_count("HELLO") == 73
    assert shapes.text_dot_count("hi") == 28
    assert shapes.text_dot_count(" ") == 0
    pts = shapes.text("HI", 1.5)
    assert pts.shape == (28, 2)
    assert pdist(pts).min() == pytest.approx(1.5)
    assert pts[:, 1].max() - pts[:, 1].min() == pytest.approx((GLYPH_ROWS - 1) * 1.5)
    np.testing.assert_allclose((pts.max(axis=0) + pts.min(axis=0)) / 2, 0.0, atol=1e-12)
    # H spans columns 0-4, I columns 7-9 (one blank column between the cells).
    assert pts[:, 0].max() - pts[:, 0].min() == pytest.approx(9 * 1.5)


def test_text_reports_characters_the_font_lacks():
    assert shapes.unsupported_chars("HÉ€É!♥") == "É€"
    assert shapes.unsupported_chars("Go 2 it?!-.:") == ""


def test_place_vertical_maps_u_to_x_and_v_to_z():
    out = shapes.place([[1.0, 2.0]], (10.0, 20.0, 30.0), "vertical")
    np.testing.assert_allclose(out, [[11.0, 20.0, 32.0]])


def test_place_horizontal_maps_u_to_x_and_v_to_y():
    out = shapes.place([[1.0, 2.0]], (10.0, 20.0, 30.0), "horizontal")
    np.testing.assert_allclose(out, [[11.0, 22.0, 30.0]])


def test_place_rotates_counter_clockwise_in_the_plane():
    out = shapes.place([[1.0, 0.0]], (0.0, 0.0, 5.0), "vertical", 90.0)
    np.testing.assert_allclose(out, [[0.0, 0.0, 6.0]], atol=1e-12)
    out = shapes.place([[1.0, 0.0]], (0.0, 0.0, 5.0), "horizontal", 90.0)
    np.testing.assert_allclose(out, [[0.0, 1.0, 5.0]], atol=1e-12)


def test_place_3d_points_ignore_the_plane_and_turn_about_the_vertical():
    out = shapes.place([[1.0, 0.0, 2.0]], (0.0, 0.0, 10.0), "vertical", 90.0)
    np.testing.assert_allclose(out, [[0.0, 1.0, 12.0]], atol=1e-12)


def test_csv_points_parse_with_a_header_in_any_column_order():
    pts = shapes.parse_points_csv("id,z,x,y\n1,3,1,2\n\n2,6,4,5\n")
    np.testing.assert_allclose(pts, [[1, 2, 3], [4, 5, 6]])


@pytest.mark.parametrize(("content", "line", "message"), [
    ("", 0, "the file is empty"),
    ("x,y\n1,2\n", 1, "has no column 'z'"),
    ("x,y,z\n1,2,3\n1,abc,3\n", 3, "'y' is not a number"),
    ("x,y,z\n1,2\n", 2, "2 values but the header has 3 columns"),
    ("x,y,z\n", 1, "no points"),
])
def test_csv_problems_name_the_line(content, line, message):
    with pytest.raises(shapes.CsvProblem) as info:
        shapes.parse_points_csv(content)
    assert info.value.line == line
    assert message in info.value.message
