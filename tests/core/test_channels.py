"""ambid.channels: a layout of any number of axes and the channel names that follow from it."""

import pytest
from ambid.channels import FIVE_AXIS, RADIAL, Layout, bearing_of, direction_of, split_name


def test_the_default_rig_keeps_its_names_and_order():
    assert RADIAL.outputs == ("y_a_x", "y_b_x", "y_a_y", "y_b_y")
    assert RADIAL.inputs == ("u_a_x", "u_b_x", "u_a_y", "u_b_y")
    assert RADIAL.measurement_names[8:12] == ("ic_a_x", "ic_b_x", "ic_a_y", "ic_b_y")
    assert RADIAL.radial_pairs == ((0, 2), (1, 3)) and RADIAL.axial == ()


@pytest.mark.parametrize("axes, pairs, axial", [
    (("z",), (), (0,)),                                   # a single-axis (axial) rig
    (("a_x",), (), ()),                                   # one radial axis
    (("a_x", "b_x"), (), ()),                             # one plane: x only
    (("a_x", "a_y"), ((0, 1),), ()),                      # one bearing, both axes
    (("a_x", "b_x", "a_y", "b_y", "z"), ((0, 2), (1, 3)), (4,)),
])
def test_any_number_of_axes(axes, pairs, axial):
    lay = Layout(axes)
    assert len(lay) == len(axes) and lay.radial_pairs == pairs and lay.axial == axial
    assert Layout.from_names(lay.outputs) == lay == Layout.from_names(lay.excitations)
    assert [lay.index(n) for n in lay.inputs] == list(range(len(axes)))
    assert lay.units("y") == ("m",) * len(axes) and lay.units("ic") == ("A",) * len(axes)


def test_names_are_read_not_assumed():
    assert split_name("ic_b_y") == ("ic", "b_y") and split_name("y_z") == ("y", "z")
    assert bearing_of("b_y") == "b" and bearing_of("z") == "z" and direction_of("z") == "z"
    assert bearing_of("front") == "front" and direction_of("front") == ""
    assert FIVE_AXIS.bearings == ("a", "b", "z")
    for bad in ("a_x", "q_a_x", "y_"):
        with pytest.raises(ValueError):
            split_name(bad)
    with pytest.raises(ValueError, match="mix"):
        Layout.from_names(["y_a_x", "u_b_x"])
    with pytest.raises(ValueError, match="repeat"):
        Layout(("a_x", "a_x"))
    with pytest.raises(ValueError):
        Layout(())
