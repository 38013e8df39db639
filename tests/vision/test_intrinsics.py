import pytest

from app.vision.intrinsics import parse_intrinsics

GOOD = {"width": 640, "height": 480, "K": [[500, 0, 320], [0, 500, 240], [0, 0, 1]], "dist": [0.1, 0, 0, 0, 0]}


def test_good_intrinsics_parse():
    cam = parse_intrinsics(GOOD)
    assert cam.K_array[0, 2] == 320 and cam.dist_array.shape == (5,)


@pytest.mark.parametrize("change, match", [
    ({"K": [[500, 0, 320], [0, 500, 240]]}, "K must be 3x3"),
    ({"K": [[-5, 0, 320], [0, 500, 240], [0, 0, 1]]}, "focal lengths must be positive"),
    ({"dist": [0, 0, 0]}, "4, 5, 8, 12 or 14 coefficients"),
    ({"width": 0}, "at width: Input should be greater than 0"),
])
def test_bad_intrinsics_say_why(change, match):
    with pytest.raises(ValueError, match=match):
        parse_intrinsics({**GOOD, **change})
