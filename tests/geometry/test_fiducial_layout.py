import numpy as np
import pytest

from app.geometry.fiducial_layout import DEFAULT_PLACEMENT_SIGMA, parse_layout, placement_sigma
from app.geometry.transforms import pose_from_xyz_euler


def layout(**marker):
    m = {"id": 7, "size_mm": 40.0, "T_table_marker": pose_from_xyz_euler(100, 50, 0).tolist()}
    m.update(marker)
    return {"dictionary": "DICT_5X5_100", "markers": [m]}


def test_corners_follow_the_design_convention():
    lay = parse_layout(layout())
    c = lay.markers[0].corners_table_mm()
    assert np.allclose(c, [[80, 70, 0], [120, 70, 0], [120, 30, 0], [80, 30, 0]])


@pytest.mark.parametrize(
    "data, match",
    [
        ({"dictionary": "DICT_9X9_1", "markers": []}, "unknown ArUco dictionary"),
        (layout(id=100), "marker id 100 is not in DICT_5X5_100"),
        (layout(size_mm=-1), "greater than 0"),
        (layout(T_table_marker=np.diag([1, 1, 2, 1]).tolist()), "T_table_marker of marker 7: rotation not orthonormal"),
        ({"dictionary": "DICT_5X5_100", "markers": [layout()["markers"][0]] * 2}, "marker id 7 appears twice"),
        ({**layout(), "placement_sigma": {"position_mm": -0.1}},
         "at placement_sigma.position_mm: .*greater than or equal to 0"),
        ({**layout(), "placement_sigma": {"scale_rel": 0.5}}, "at placement_sigma.scale_rel"),
    ],
)
def test_bad_layouts_are_refused_with_a_reason(data, match):
    with pytest.raises(ValueError, match=match):
        parse_layout(data)


def test_a_declared_placement_sigma_is_kept_and_missing_values_take_the_default():
    """The layout says how well its markers sit where it puts them; what it leaves out is the default,
    and a stored layout (``model_dump``) still says it."""
    stored = parse_layout({**layout(), "placement_sigma": {"position_mm": 0.2}}).model_dump()
    assert placement_sigma(stored) == (0.2, DEFAULT_PLACEMENT_SIGMA[1], DEFAULT_PLACEMENT_SIGMA[2])
    assert placement_sigma(parse_layout(layout()).model_dump()) == DEFAULT_PLACEMENT_SIGMA
