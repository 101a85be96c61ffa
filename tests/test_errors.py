"""Each package's errors under its base class; library input errors are TrajgenErrors."""

import pytest

from trajgen import BlendingSpline, TrajgenError
from trajgen.drivers.errors import DriverError, PacketError
from trajgen.errors import BadArgument, NoCircleError
from trajgen.online import ChangeTooLate, OnlineSpline
from trajgen.sim.errors import IdentifyError, SimError

QUATS = [[1.0, 0, 0, 0], [0, 1.0, 0, 0], [1.0, 0, 0, 0]]


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda: BlendingSpline(QUATS, [0.0, 1.0, 1.0]), "strictly increasing"),
        (lambda: BlendingSpline(QUATS, [0.0, 1.0]), r"Expected `times` to have shape \(3,\)"),
        (lambda: BlendingSpline([[1.0, 0, 0]], [0.0]), r"Expected `quats` to have shape \(N, 4\)"),
        (lambda: BlendingSpline(QUATS, [0.0, 1.0, 2.0], k=30), "Expected `k` to be an integer"),
        (lambda: BlendingSpline(QUATS, [0.0, 1.0, 2.0], boundary="x"), "Expected `boundary`"),
        (lambda: BlendingSpline(QUATS, [0.0, 1.0, 2.0])(5.0), "outside"),
        (lambda: OnlineSpline(QUATS[0], k=4), "Expected `k` to be an integer in 1..3"),
    ],
)
def test_bad_arguments_are_trajgen_errors_and_value_errors(make, message):
    with pytest.raises(BadArgument, match=message) as caught:
        make()
    assert isinstance(caught.value, TrajgenError) and isinstance(caught.value, ValueError)


def test_a_wrong_type_stays_a_type_error():
    with pytest.raises(TypeError, match="Expected `k` to be an integer"):
        BlendingSpline(QUATS, [0.0, 1.0, 2.0], k=2.5)


def test_stray_errors_are_under_their_package_base():
    assert issubclass(NoCircleError, TrajgenError)
    assert issubclass(ChangeTooLate, TrajgenError)
    assert issubclass(PacketError, DriverError) and issubclass(PacketError, ValueError)
    assert issubclass(IdentifyError, SimError) and issubclass(IdentifyError, ValueError)


def test_a_reversal_raises_no_circle_as_a_trajgen_error():
    from trajgen.local_curves import NoCircleError as same

    assert same is NoCircleError
    with pytest.raises(TrajgenError, match=r"\(a reversal\): no circle passes through them"):
        BlendingSpline(QUATS, [0.0, 1.0, 2.0], local="circle")


def test_driver_and_sim_bad_arguments_are_under_both_bases():
    from trajgen.drivers import errors as drivers_errors
    from trajgen.drivers.units import JointMap
    from trajgen.sim import errors as sim_errors
    from trajgen.sim.limits import JointLimits

    with pytest.raises(drivers_errors.BadArgument, match=r"Expected distinct `ids`") as caught:
        JointMap([1, 1, 2])
    assert isinstance(caught.value, DriverError) and isinstance(caught.value, BadArgument)
    assert issubclass(sim_errors.BadArgument, SimError)
    assert issubclass(sim_errors.BadArgument, BadArgument)
    with pytest.raises(sim_errors.BadArgument, match="to have 3 entries"):
        JointLimits(speed_rad_s=(1.0, 1.0))


def test_no_library_module_raises_a_bare_value_error():
    """Bad input in the library is a package error (also a ValueError), never a bare one."""
    import pathlib
    import re

    root = pathlib.Path(__file__).resolve().parents[1]
    offenders = [
        f"{path.relative_to(root)}:{n}"
        for package in ("trajgen", "drivers", "sim")
        for path in sorted((root / package).rglob("*.py"))
        for n, line in enumerate(path.read_text().splitlines(), 1)
        if re.search(r"\braise ValueError\(", line)
    ]
    assert offenders == []
