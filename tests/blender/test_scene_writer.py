"""The add-on's convention: addon/export/ produces plain data, and addon/scene_writer.py is the
only module that writes the core scene. A scan of the add-on's sources (ast, no bpy needed)."""

import ast
from pathlib import Path

from blender_util import REPO

ADDON = Path(REPO) / "addon"
WRITER = ADDON / "scene_writer.py"
# Build options of pc.Scene that a write sets (attribute assignments, not calls).
SCENE_PROPERTIES = frozenset(("dynamic", "spatial_splits", "light_tree", "compact_bvh", "build_quality"))
WRITER_PREFIXES = ("add_", "set_", "clear_")


def _receiver_name(node):
    """The name of the object an attribute is taken on: `scene` of scene.x, `core_scene` of
    self.core_scene.x, or None."""
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        return node.attr
    return None


def _is_scene(node):
    name = _receiver_name(node)
    return name is not None and name.lower().endswith("scene")


def _string_start(node):
    """The leading constant text of a str or f-string node, or None."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value
    if isinstance(node, ast.JoinedStr) and node.values and isinstance(node.values[0], ast.Constant):
        return node.values[0].value
    return None


def scene_writes(source, filename="<source>"):
    """(line, text) of each core scene write in Python `source`: calls of add_*/set_*/clear_*
    methods on a variable named *scene, getattr(*scene, "add_..."/"set_...") and assignments
    to the core scene's build options."""
    found = []
    for node in ast.walk(ast.parse(source, filename)):
        if isinstance(node, ast.Call):
            f = node.func
            if isinstance(f, ast.Attribute) and f.attr.startswith(WRITER_PREFIXES) and _is_scene(f.value):
                found.append((node.lineno, f"{_receiver_name(f.value)}.{f.attr}()"))
            elif isinstance(f, ast.Name) and f.id == "getattr" and len(node.args) >= 2 and \
                    _is_scene(node.args[0]):
                start = _string_start(node.args[1])
                if start is not None and start.startswith(WRITER_PREFIXES):
                    found.append((node.lineno, f"getattr({_receiver_name(node.args[0])}, {start!r}...)"))
        elif isinstance(node, (ast.Assign, ast.AugAssign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for t in targets:
                if isinstance(t, ast.Attribute) and t.attr in SCENE_PROPERTIES and _is_scene(t.value):
                    found.append((node.lineno, f"{_receiver_name(t.value)}.{t.attr} ="))
    return sorted(found)


def test_the_scan_finds_scene_writes():
    source = ("scene.add_mesh(p, t)\nself.scene.set_instance_transform(0, m)\n"
              "core_scene.light_tree = 'off'\ngetattr(scene, f'add_{kind}_light', None)\n"
              "scene.commit()\nengine.add_pass('Depth', 1, 'Z')\nscene.render.resolution_x = 8\n")
    assert [text for _, text in scene_writes(source)] == [
        "scene.add_mesh()", "scene.set_instance_transform()", "core_scene.light_tree =",
        "getattr(scene, 'add_'...)"]


def test_only_the_scene_writer_writes_the_core_scene():
    assert scene_writes(WRITER.read_text(), str(WRITER)), "the scan no longer sees the writer's calls"
    offenders = []
    for path in sorted(ADDON.rglob("*.py")):
        if path == WRITER:
            continue
        for line, text in scene_writes(path.read_text(), str(path)):
            offenders.append(f"{path.relative_to(REPO)}:{line}: {text}")
    assert not offenders, ("core scene writes outside addon/scene_writer.py (export/ returns plain "
                           "data; write through scene_writer):\n" + "\n".join(offenders))
