import math

import numpy as np
import pytest

from trajgen.errors import KeyframeFileError, TrajgenError
from trajgen.servo_table import SERVOS, servo_spec
from trajgen.validate import check_choice, check_keys, check_number, check_numbers


@pytest.mark.parametrize(
    ("value", "kwargs", "exc", "match"),
    [
        (True, {}, TypeError, r"Expected `x` to be a finite number, got True\."),
        ("1", {}, TypeError, r"Expected `x` to be a finite number, got '1'\."),
        (math.nan, {}, ValueError, r"Expected `x` to be a finite number, got nan\."),
        (-1, {"low": 0}, ValueError, r"Expected `x` to be a finite number >= 0, got -1\."),
        (0.0, {"low": 0, "low_open": True}, ValueError, r"a finite number > 0, got 0\.0"),
        (2, {"low": 0, "high": 1, "low_open": True}, ValueError, r"in \(0, 1\], got 2"),
        (1.5, {"integer": True, "low": 1, "high": 6}, TypeError, r"an integer in 1\.\.6, got 1\.5"),
        (np.bool_(True), {"integer": True}, TypeError, r"an integer, got"),
    ],
)
def test_check_number_names_the_argument_and_what_arrived(value, kwargs, exc, match):
    with pytest.raises(exc, match=match):
        check_number("x", value, **kwargs)


def test_check_number_converts_and_accepts_numpy():
    assert check_number("x", np.float32(0.5), low=0) == 0.5
    assert type(check_number("k", np.int64(3), integer=True)) is int


def test_the_file_form_uses_the_error_factory():
    def error(problem):
        return KeyframeFileError(f"f.toml: [spline] k: {problem}")

    with pytest.raises(KeyframeFileError, match=r"^f.toml: \[spline\] k: expected an integer"):
        check_number("k", "two", integer=True, error=error)
    with pytest.raises(KeyframeFileError, match=r"expected an integer in 0\.\.252, got 300 in"):
        check_numbers("ids", [1, 2, 300], 3, integer=True, low=0, high=252, error=error)
    assert issubclass(KeyframeFileError, TrajgenError) and issubclass(TrajgenError, ValueError)


def test_check_numbers_and_choice():
    assert check_numbers("v", [1, 2.5, 3], 3) == (1.0, 2.5, 3.0)
    with pytest.raises(ValueError, match=r"Expected `v` to be a list of 3 numbers, got \[1, 2\]"):
        check_numbers("v", [1, 2], 3)
    with pytest.raises(ValueError, match=r"`mode` to be one of \('a', 'b'\), got 'c'"):
        check_choice("mode", "c", ("a", "b"))


def test_one_ratings_table_and_names_in_any_case():
    assert servo_spec(" xm430-w350 ") is SERVOS["XM430-W350"]
    with pytest.raises(ValueError, match=r"unknown model 'MX-28' \(known: XM430-W350"):
        servo_spec("MX-28")
    from trajgen.drivers.control_table import MODELS
    from trajgen.sim.servos import SERVOS as SIM_SERVOS

    for name, rating in SERVOS.items():  # both packages read the same figures
        sim = SIM_SERVOS[name]
        assert MODELS[name].stall_torque_nm == sim.stall_torque_nm == rating.stall_torque_nm
        assert MODELS[name].no_load_speed_rad_s == SIM_SERVOS[name].no_load_speed_rad_s
        assert MODELS[name].number == rating.number


def test_check_keys_one_message_shape_for_every_kind_of_key():
    def error(problem):
        return KeyframeFileError(f"f.toml: [gimbal]: {problem}")

    check_keys({"a": 1}, ("a", "b"), error=error)  # known keys pass
    with pytest.raises(
        KeyframeFileError, match=r"^f.toml: \[gimbal\]: unknown key 'c' \(known: a, b\)$"
    ):
        check_keys({"a": 1, "c": 2}, ("a", "b"), error=error)
    with pytest.raises(KeyframeFileError, match=r"unknown joint 'yaw' \(known: pan, tilt, roll\)"):
        check_keys({"yaw": 1}, ("pan", "tilt", "roll"), error=error, kind="joint")
    # A key of megabytes (a JSON line) is shown cut, not whole.
    with pytest.raises(
        KeyframeFileError, match=r"unknown field 'xxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxx\.\.\.'"
    ):
        check_keys({"x" * 1_000_000: 1}, ("t",), error=error, kind="field")
