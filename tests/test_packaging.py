"""Import names, layering and the installed command: what a user's project sees."""

import ast
import subprocess
import sys
from pathlib import Path

import pytest

import trajgen

ROOT = Path(__file__).resolve().parents[1]


def test_user_modules_named_sim_and_drivers_do_not_shadow_ours(tmp_path):
    (tmp_path / "sim.py").write_text("raise SystemExit('the user sim.py was imported')\n")
    (tmp_path / "drivers.py").write_text("raise SystemExit('the user drivers.py was imported')\n")
    code = (
        "import trajgen.sim, trajgen.drivers, trajgen.drivers.virtual.bus\n"
        "from trajgen.sim import assert_torque_ok\n"
        "import sim, drivers\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=60
    )
    # Ours import cleanly; the user's own `sim` is still theirs (it runs and exits).
    assert proc.returncode == 1
    assert proc.stderr.strip() == "the user sim.py was imported"


def _imports(path: Path) -> set[str]:
    """Every module name a source file imports, at any depth in the file."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
    return names


@pytest.mark.parametrize(
    ("folder", "forbidden"),
    [
        (
            "trajgen",
            ("trajgen.sim", "trajgen.drivers", "trajgen.cli", "trajgen.jobs", "mujoco")
            + ("dynamixel_sdk",),
        ),
        ("drivers", ("trajgen.cli", "trajgen.jobs", "trajgen.sim", "mujoco")),
        ("sim", ("trajgen.cli", "trajgen.jobs", "trajgen.drivers", "dynamixel_sdk")),
        ("trajgen/jobs", ("trajgen.cli",)),
    ],
)
def test_packages_never_import_the_command_line_or_each_other(folder, forbidden):
    offenders = []
    for path in sorted((ROOT / folder).rglob("*.py")):
        if folder == "trajgen" and path.relative_to(ROOT / folder).parts[0] in ("cli", "jobs"):
            continue  # the command line and the jobs are where the three meet
        if path.name == "__main__.py":
            continue
        bad = {m for m in _imports(path) if m.startswith(forbidden)}
        offenders += [f"{path.relative_to(ROOT)}: {m}" for m in sorted(bad)]
    assert offenders == []


def test_version_flag_prints_the_package_version():
    proc = subprocess.run(
        [sys.executable, "-m", "trajgen", "--version"], capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 0
    assert proc.stdout.strip() == f"trajgen {trajgen.__version__}"


def test_the_package_ships_its_typing_marker():
    assert (Path(trajgen.__file__).parent / "py.typed").is_file()


def test_the_dynamixel_sdk_pin_claims_only_what_is_tested():
    # The suite runs on the installed dynamixel-sdk; the pin may not claim a lower
    # release series than the one installed (3.x had no Easy SDK and was never run
    # here: the pin was raised from ">=3.7" to ">=4.1", the version the suite ran on).
    import tomllib
    from importlib.metadata import version

    from packaging.requirements import Requirement
    from packaging.version import Version

    project = tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text())
    pins = [Requirement(d) for d in project["project"]["dependencies"]]
    (sdk,) = [r for r in pins if r.name == "dynamixel-sdk"]
    installed = Version(version("dynamixel-sdk"))
    assert installed in sdk.specifier, f"installed {installed} outside the pin {sdk}"
    lowest = [Version(s.version) for s in sdk.specifier if s.operator == ">="]
    assert len(lowest) == 1, f"expected one lower bound in {sdk}"
    assert lowest[0].release[:2] == installed.release[:2], (
        f"the pin {sdk} claims {lowest[0]}, but the suite runs on {installed}: test the "
        "lowest version claimed, or raise the pin to the tested one"
    )
