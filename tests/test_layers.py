"""The structure the code keeps (docs/design.md): layers that import one way, light lower layers,
compiled kernels with few positional parameters, and libraries through their public APIs."""

import ast
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("testbed", "sensors", "estimators", "datasets")
MAX_KERNEL_PARAMETERS = 8


def source_files():
    for package in PACKAGES:
        yield from sorted((ROOT / package).rglob("*.py"))


def test_import_linter_contracts_are_kept():
    lint = Path(sys.executable).with_name("lint-imports")
    result = subprocess.run([str(lint)], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout[-3000:]


def test_sensors_and_estimators_import_without_the_simulation_or_datasets():
    code = ("import sys, sensors, estimators; print(sorted(m for m in sys.modules if m.split('.')[0] in "
            "('dartpy', 'datasets') or m.startswith(('testbed.world', 'testbed.runtime', 'testbed.tools'))))")
    result = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0 and result.stdout.strip() == "[]", result.stdout + result.stderr


def test_compiled_functions_take_at_most_eight_positional_parameters():
    wide = []
    for path in source_files():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef) and any("jit" in ast.unparse(d) for d in node.decorator_list):
                count = len(node.args.posonlyargs) + len(node.args.args)
                if count > MAX_KERNEL_PARAMETERS:
                    wide.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name} ({count})")
    assert wide == []


def test_no_private_names_of_libraries():
    private = re.compile(r"_Writer__|_chunk_builder|^\s*(from|import)\s+(mcap|google|numba|dartpy|scipy|numpy)\S*\._")
    hits = [f"{path.relative_to(ROOT)}:{number}" for path in source_files()
            for number, line in enumerate(path.read_text().splitlines(), 1) if private.search(line)]
    assert hits == []
