"""The map is the only writer of its data (`pld_slam.mapping.map` docstring): keyframe poses, landmark
columns and observations change through its methods. Landmark columns are read-only views at run time;
the source is checked for the writes a read-only view cannot stop."""

import ast
from pathlib import Path

import numpy as np
import pytest

import pld_slam
from pld_slam.mapping.landmarks import PointLandmarks

LIBRARY = Path(pld_slam.__file__).parent
WRITERS = {LIBRARY / "mapping" / "map.py", LIBRARY / "mapping" / "landmarks.py"}


def assignment_targets(tree: ast.AST) -> list[ast.expr]:
    """Every target of an assignment, augmented assignment or annotated assignment in ``tree``, tuples unpacked."""
    targets = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign):
            targets.extend(node.targets)
        elif isinstance(node, ast.AugAssign | ast.AnnAssign):
            targets.append(node.target)
    unpacked = []
    while targets:
        target = targets.pop()
        if isinstance(target, ast.Tuple | ast.List):
            targets.extend(target.elts)
        else:
            unpacked.append(target)
    return unpacked


def map_writes(path: Path) -> list[str]:
    """``file:line: what`` for each write of the map's data in one source file: a keyframe pose assigned, a
    landmark's observers assigned, or a column taken `writable`."""
    tree = ast.parse(path.read_text(), filename=str(path))
    found = []
    for target in assignment_targets(tree):
        if isinstance(target, ast.Attribute) and target.attr == "T_c_w":
            found.append((target.lineno, "assigns T_c_w"))
        if (isinstance(target, ast.Subscript) and isinstance(target.value, ast.Attribute)
                and target.value.attr == "observers"):
            found.append((target.lineno, "assigns observers[...]"))
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "writable":
            found.append((node.lineno, "calls writable()"))
    return [f"{path}:{line}: {what}" for line, what in sorted(found)]


def test_no_library_module_but_the_map_writes_the_map():
    writes = [write for path in sorted(LIBRARY.rglob("*.py")) if path not in WRITERS for write in map_writes(path)]
    assert writes == []


def test_the_check_finds_each_kind_of_write(tmp_path):
    source = tmp_path / "writer.py"
    source.write_text("keyframe.T_c_w = pose\nkind.observers[3] = {}\nkind.writable('found')[ids] += 1\n"
                      "a, keyframe.T_c_w = 1, pose\n")
    assert [write.split(": ", 1)[1] for write in map_writes(source)] == [
        "assigns T_c_w", "assigns observers[...]", "calls writable()", "assigns T_c_w"]


@pytest.mark.parametrize("column", ["geometry", "descriptor", "normal", "found", "alive", "max_distance"])
def test_landmark_columns_read_as_read_only_views(column):
    points = PointLandmarks()
    points.add(np.zeros((2, 3)), np.zeros((2, 32), dtype=np.uint8), first_keyframe=0)
    with pytest.raises(ValueError, match="read-only"):
        getattr(points, column)[0] = getattr(points, column)[1]
    points.writable(column)[0] = points.writable(column)[1]
