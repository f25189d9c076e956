"""Colour parsing and gradients."""

from __future__ import annotations

import numpy as np
import pytest

from groundctl.show.colors import ColorError, gradient, gradient_parameter, parse_color


@pytest.mark.parametrize(("value", "rgb"), [
    ("#ff8800", (255, 136, 0)),
    ("#FF8800", (255, 136, 0)),
    ("#f80", (255, 136, 0)),
    ([255, 136, 0], (255, 136, 0)),
    ("gold", (255, 200, 0)),
    ("White", (255, 255, 255)),
])
def test_parse_color(value, rgb):
    np.testing.assert_allclose(parse_color(value), np.array(rgb) / 255.0)


@pytest.mark.parametrize(("value", "message"), [
    ("#ff88", "'#ff88' is not a colour; write '#rrggbb', '#rgb', [r, g, b]"),
    ("orangey", "'orangey' is not a colour"),
    ([255, 136], "[255, 136] is not a colour; [r, g, b] needs three integers 0-255"),
    ([256, 0, 0], "needs three integers 0-255"),
    ([1.0, 0.5, 0.0], "needs three integers 0-255"),
    (7, "7 is not a colour"),
])
def test_bad_colors_say_what_is_accepted(value, message):
    with pytest.raises(ColorError, match=None) as info:
        parse_color(value)
    assert message in str(info.value)


def test_gradient_runs_along_u_from_first_to_last_stop():
    local = np.array([[-1.0, 0.0], [0.0, 5.0], [1.0, 0.0]])
    t = gradient_parameter(local, "u")
    np.testing.assert_allclose(t, [0.0, 0.5, 1.0])
    stops = np.array([parse_color("#ff0000"), parse_color("#0000ff")])
    np.testing.assert_allclose(gradient(stops, t), [[1, 0, 0], [0.5, 0, 0.5], [0, 0, 1]])


def test_gradient_axes_v_radial_and_3d():
    local = np.array([[0.0, -2.0], [0.0, 0.0], [3.0, 2.0]])
    np.testing.assert_allclose(gradient_parameter(local, "v"), [0.0, 0.5, 1.0])
    ring = np.array([[0.0, 0.0], [1.0, 0.0], [-1.0, 0.0], [0.0, 2.0], [0.0, -2.0]])
    np.testing.assert_allclose(gradient_parameter(ring, "radial"), [0, 0.5, 0.5, 1, 1])
    # 3D local points (sphere): v is z, what the audience sees as up.
    ball = np.array([[0.0, 9.0, -1.0], [0.0, -9.0, 1.0]])
    np.testing.assert_allclose(gradient_parameter(ball, "v"), [0.0, 1.0])


def test_three_stop_gradient_passes_through_the_middle_stop():
    stops = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]])
    np.testing.assert_allclose(gradient(stops, np.array([0.5])), [[0, 1, 0]])


def test_degenerate_gradient_is_the_first_colour():
    t = gradient_parameter(np.zeros((3, 2)), "u")
    np.testing.assert_allclose(t, 0.0)
