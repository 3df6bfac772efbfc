"""Stored Cycles reference renders for the Blender tests (docs/building.md, "CI time").

Cycles' image of a scene, at given settings, samples and seed, with a given `bpy` build, does not
change when Pathlight changes, so the tests keep it in `tests/cycles_refs/` under a fingerprint of
everything the render reads: a deterministic walk of the RNA of every render-relevant ID in
`bpy.data` (values written exactly, ID pointers as type + name, big arrays hashed as bytes through
`foreach_get`, external files by content), plus the `bpy` build and what was asked for.

PATHLIGHT_CYCLES_REFS selects the mode:
  use     (the default under pytest: tests/conftest.py sets it) a stored reference if there is
          one, else render with Cycles and store it;
  render  (the default elsewhere: bench scripts and one-off measurements time their renders, so a
          hit would be a lie) always render, never read or write (the full, uncached comparison);
  check   render, compare with the stored reference (fail beyond float noise), store if missing;
  refresh render and (over)write the reference.
Every key a process uses is recorded in build/cycles_refs_used/ with how and the seconds it took
(`build.py test --refs prune`; the summary line of a run).
"""

import hashlib
import json
import os
import re
import shutil
import tempfile
import time
import zlib
from pathlib import Path

import bpy
import numpy as np

REPO = Path(__file__).resolve().parents[2]
REFS_DIR = REPO / "tests" / "cycles_refs"
USED_DIR = REPO / "build" / "cycles_refs_used"
MODES = ("use", "render", "check", "refresh")
# Bump when the walk or the stored format changes on purpose: every key changes with it.
FINGERPRINT_VERSION = 1

# ID collections of bpy.data that a render can read. Left out: UI and editing data (screens,
# window managers, workspaces, brushes, palettes, paint curves), grease pencil (Cycles does not
# render it), sounds and speakers, masks, light probes (EEVEE only).
ID_COLLECTIONS = ("scenes", "objects", "collections", "meshes", "curves", "hair_curves", "pointclouds",
                  "volumes", "metaballs", "lattices", "armatures", "shape_keys", "lights", "cameras",
                  "materials", "worlds", "node_groups", "images", "textures", "particles", "actions",
                  "texts", "fonts", "linestyles", "cache_files", "movieclips", "libraries")

# Runtime state, UI state and values derived from other data; none of it reaches Cycles' image,
# and some of it differs between processes or with what ran before (found by walking the same
# scene built in two processes and by rendering it in between).
SKIP_ALWAYS = frozenset({
    "rna_type", "session_uid", "is_evaluated", "original", "users", "use_extra_user", "is_editable",
    "tag", "is_runtime_data", "is_dirty", "bindcode", "preview", "is_library_indirect",
    "library_weak_reference", "asset_data", "override_library", "is_missing", "use_fake_user",
    "select", "is_editmode", "total_vert_sel", "total_edge_sel", "total_face_sel", "dimensions",
    "is_active_output", "show_expanded", "show_options", "show_preview", "show_texture",
    "is_property_readonly", "bl_description", "bl_icon", "bl_static_type", "internal_links",
    "is_multi_input", "is_linked", "is_output", "is_unavailable",
})
# Per type: (class name, property).
SKIP_TYPED = frozenset({
    ("RenderSettings", "filepath"),        # the output file: a temporary path, not read
    ("RenderSettings", "threads"), ("RenderSettings", "threads_mode"),  # the image does not depend on them
    ("RenderSettings", "stamp_note_text"), ("BakeSettings", "filepath"),
    ("Scene", "tool_settings"), ("Scene", "cursor"), ("Scene", "eevee"), ("Scene", "display"),
    ("Scene", "hydra"), ("Scene", "grease_pencil_settings"), ("Scene", "safe_areas"),
    ("Scene", "transform_orientation_slots"), ("Scene", "keying_sets_all"), ("Scene", "statistics"),
    ("Scene", "frame_current_final"), ("Scene", "frame_float"),
    # Duplicates of the mesh's attributes (positions, corners, edges, UV maps, colours), hashed there.
    ("Mesh", "vertices"), ("Mesh", "edges"), ("Mesh", "loops"), ("Mesh", "loop_triangles"),
    ("Mesh", "loop_triangle_polygons"), ("Mesh", "vertex_normals"), ("Mesh", "polygon_normals"),
    ("Mesh", "corner_normals"), ("Mesh", "uv_layers"), ("Mesh", "vertex_colors"),
    ("Mesh", "color_attributes"), ("Mesh", "uv_layer_clone"), ("Mesh", "uv_layer_stencil"),
    ("Mesh", "normals_domain"), ("Mesh", "polygons"), ("Mesh", "attributes"),  # special_Mesh
    ("Image", "size"), ("Image", "has_data"), ("Image", "depth"), ("Image", "channels"),
    ("Image", "is_float"), ("Image", "pixels"), ("Image", "bindcode"), ("Image", "frame_duration"),
    ("Image", "render_slots"), ("Image", "resolution"), ("UDIMTile", "size"), ("UDIMTile", "channels"),
    ("PackedFile", "data"),                # hashed as bytes (struct())
    ("Volume", "grids"),                   # loaded from the .vdb file, which is hashed
    ("Curves", "normals"),                 # computed from the points and tilt; differs between runs
    ("FieldSettings", "seed"),             # random per new particle settings; no test uses a noisy field
    ("ViewLayer", "depsgraph"),            # the evaluated copy of everything walked here
    ("Object", "matrix_world"), ("Object", "matrix_local"),  # derived from location, parent, ...
    ("Object", "bound_box"), ("Object", "mode"), ("Object", "field"), ("Object", "collision"),
    ("Text", "lines"), ("Text", "current_line"), ("Text", "select_end_line"), ("Text", "current_character"),
    ("Text", "select_end_character"), ("Text", "current_line_index"), ("Text", "select_end_line_index"),
    ("Text", "current_column"), ("Text", "select_end_column"),
})
MAX_DEPTH = 12
BIG = 16        # collections longer than this are hashed per property through foreach_get
NUMERIC = {"FLOAT": np.float64, "INT": np.int64, "BOOLEAN": np.bool_}



def is_dir_of_tiles(value, lib):
    """Whether path `value` names UDIM tiles (a <UDIM> or <UVTILE> token) in an existing folder."""
    try:
        real = Path(bpy.path.abspath(value, library=lib))
    except Exception:
        return False
    return ("<UDIM>" in real.name or "<UVTILE>" in real.name) and real.parent.is_dir()


def _stable_bytes(path):
    """A file's bytes, less what changes each time the same data is written: an OpenVDB file's
    header holds a random UUID (36 characters after the magic, versions, library version and the
    grid-offsets flag, from file version 220 on)."""
    data = path.read_bytes()
    if data[:4] == b" BDV" and len(data) >= 57 and int.from_bytes(data[8:12], "little") >= 220:
        data = data[:21] + b"0" * 36 + data[57:]
    return data

class _Walker:
    def __init__(self):
        self.h = hashlib.sha256()
        self.lines = None  # a list to debug with (what differs between two keys)

    def put(self, text):
        self.h.update(text.encode("utf-8", "surrogateescape"))
        self.h.update(b"\n")
        if self.lines is not None:
            self.lines.append(text)

    def put_bytes(self, label, data):
        digest = hashlib.sha256(data).hexdigest()
        self.put(f"{label}#{len(data)}:{digest}")

    # -- RNA ---------------------------------------------------------------------------------

    def walk_id(self, idb):
        self.put(f"ID {type(idb).__name__} {idb.name_full!r}")
        self.seen = set()
        self.struct(idb, "", 0)
        special = getattr(self, "special_" + type(idb).__name__, None)
        if special is None:
            for cls in type(idb).__mro__:
                special = getattr(self, "special_" + cls.__name__, None)
                if special:
                    break
        if special:
            special(idb)

    def struct(self, s, path, depth):
        key = (s.as_pointer(), s.bl_rna.identifier)
        if key in self.seen:
            self.put(f"{path}=<ref {self._path_of(s)}>")
            return
        self.seen.add(key)
        if depth > MAX_DEPTH:
            self.put(f"{path}=<deep>")
            return
        cls = type(s).__name__
        if isinstance(s, bpy.types.PackedFile):  # packed image, volume, font: its bytes
            self.put_bytes(f"{path}.data", bytes(s.data))
        for prop in s.bl_rna.properties:
            name = prop.identifier
            if name in SKIP_ALWAYS or name.startswith("pathlight") or (cls, name) in SKIP_TYPED:
                continue
            if (prop.bl_rna.identifier, name) in SKIP_TYPED:
                continue
            self.prop(s, prop, f"{path}.{name}", depth)

    def prop(self, s, prop, path, depth):
        name = prop.identifier
        try:
            value = getattr(s, name)
        except Exception as exc:  # a property that cannot be read here (context-dependent)
            self.put(f"{path}!{type(exc).__name__}")
            return
        t = prop.type
        if t == "POINTER":
            self.pointer(value, path, depth)
        elif t == "COLLECTION":
            self.collection(value, path, depth)
        elif t == "STRING":
            if prop.subtype in ("FILE_PATH", "DIR_PATH") and value:
                self.file(path, s, value)
            else:
                self.put(f"{path}={value!r}")
        elif t == "ENUM":
            self.put(f"{path}={sorted(value) if isinstance(value, set) else value!r}")
        else:
            if getattr(prop, "is_array", False) or hasattr(value, "__len__"):
                value = _plain(value)
            self.put(f"{path}={value!r}")

    def pointer(self, value, path, depth):
        if value is None:
            self.put(f"{path}=None")
        elif isinstance(value, bpy.types.ID) and not value.is_embedded_data:
            self.put(f"{path}=<{type(value).__name__} {value.name_full!r}>")
        else:  # a nested struct, or an embedded ID (a material's node tree, the master collection)
            self.put(f"{path}:{type(value).__name__}")
            self.struct(value, path, depth + 1)

    def collection(self, coll, path, depth):
        n = len(coll)
        self.put(f"{path}[{n}]")
        if n == 0:
            return
        first_type = type(coll[0])
        # Items of several types (a node's sockets, a curve's attributes) one by one: reading
        # one type's property across all of them with foreach_get returns undefined bytes.
        if n <= BIG or not all(type(i) is first_type for i in coll):
            for i, item in enumerate(coll):
                if not isinstance(item, bpy.types.bpy_struct):
                    self.put(f"{path}[{i}]={_plain(item)!r}")
                elif isinstance(item, bpy.types.ID) and not item.is_embedded_data:
                    self.put(f"{path}[{i}]=<{type(item).__name__} {item.name_full!r}>")
                else:
                    self.put(f"{path}[{i}]:{type(item).__name__}")
                    self.struct(item, f"{path}[{i}]", depth + 1)
            return
        # Many items (vertices, attribute values, keyframes, text lines): per property at once.
        first = coll[0]
        if not all(isinstance(i, bpy.types.bpy_struct) for i in coll):  # None among them
            self.put(f"{path}=" + repr([_plain(i) if not isinstance(i, bpy.types.bpy_struct) else
                                        f"{type(i).__name__}" for i in coll]))
            return
        if isinstance(first, bpy.types.ID):
            self.put(f"{path}=" + repr([f"{type(i).__name__} {i.name_full}" for i in coll]))
            return
        self.put(f"{path}:{type(first).__name__}")
        for prop in first.bl_rna.properties:
            name = prop.identifier
            if name in SKIP_ALWAYS or name.startswith("pathlight"):
                continue
            sub = f"{path}[*].{name}"
            t = prop.type
            if t in NUMERIC and (not prop.is_array or prop.array_length > 0) and not getattr(prop, "is_dynamic", False):
                size = max(1, prop.array_length) if prop.is_array else 1
                if t == "FLOAT" and prop.is_array and getattr(prop, "array_dimensions", (0, 0))[1]:
                    size = int(np.prod([d for d in prop.array_dimensions if d]))
                arr = np.empty(n * size, NUMERIC[t])
                try:
                    coll.foreach_get(name, arr)
                except Exception:  # ragged (a face's vertices): as text
                    self.put(f"{sub}={[_plain(getattr(i, name)) for i in coll]!r}")
                else:
                    self.put_bytes(sub, arr.tobytes())
            elif t in ("STRING", "ENUM") or t in NUMERIC:
                self.put(f"{sub}={[_plain(getattr(i, name)) for i in coll]!r}")
            elif t == "POINTER":
                vals = [getattr(i, name) for i in coll]
                if all(v is None or isinstance(v, bpy.types.ID) for v in vals):
                    self.put(f"{sub}={[None if v is None else v.name_full for v in vals]!r}")
                # Nested structs of many items (a vertex's groups) are left out: see the docs.
            # Collections inside many items are left out likewise.

    def _path_of(self, s):
        try:
            return f"{type(s.id_data).__name__}:{s.id_data.name_full}:{s.path_from_id()}"
        except Exception:
            return type(s).__name__

    # -- data outside RNA ----------------------------------------------------------------------

    def file(self, path, owner, value):
        """An existing file by its name and content, not where it lies (tests write theirs into
        temporary folders); anything else by the path as written."""
        lib = getattr(owner, "library", None) if isinstance(owner, bpy.types.ID) else None
        try:
            real = Path(bpy.path.abspath(value, library=lib))
            is_file = real.is_file()
        except Exception:
            is_file = False
        if is_file:
            self.put_bytes(f"{path}=<file {real.name!r}>", _stable_bytes(real))
        elif is_dir_of_tiles(value, lib):  # a UDIM path: every tile file it names
            real = Path(bpy.path.abspath(value, library=lib))
            pattern = re.escape(real.name).replace("<UDIM>", r"\d{4}").replace("<UVTILE>", r"u\d+_v\d+")
            self.put(f"{path}=<tiles {real.name!r}>")
            self.files(path, real.parent, pattern)
        else:
            self.put(f"{path}={value!r}<not a file>")

    def files(self, path, folder, pattern):
        """The files of `folder` whose name matches regex `pattern`, by name and content."""
        for f in sorted(folder.iterdir()):
            if f.is_file() and re.fullmatch(pattern, f.name):
                self.put_bytes(f"{path}<{f.name!r}>", _stable_bytes(f))

    def special_Image(self, img):
        packed = list(img.packed_files)  # their bytes: struct() hashes every PackedFile
        if img.source == "SEQUENCE":  # every frame file beside the one the path names
            real = Path(bpy.path.abspath(img.filepath, library=img.library))
            runs = list(re.finditer(r"\d+", real.stem))
            if runs and real.parent.is_dir():
                last = runs[-1]
                stem = re.escape(real.stem[:last.start()]) + r"\d+" + re.escape(real.stem[last.end():])
                self.files("frames", real.parent, stem + re.escape(real.suffix))
        # Generated, packed or edited images: their pixels (a file-backed, unedited image is its
        # file, hashed through its filepath).
        if img.source in ("GENERATED", "VIEWER") or img.is_dirty or len(packed):
            try:
                px = np.empty(len(img.pixels), np.float32)
                img.pixels.foreach_get(px)
                self.put_bytes("pixels", px.tobytes())
                self.put(f"size={tuple(img.size)}")
            except Exception as exc:
                self.put(f"pixels!{type(exc).__name__}")

    def special_Mesh(self, mesh):
        """The mesh as a set of faces, each its corners' values in order (positions and every
        point and corner attribute) with its face attributes, sorted; edges likewise by their
        ends' positions. Blender's mesh primitives come out with their faces in a different order
        from one process to the next (threaded conversion from BMesh), so hashing the arrays as
        they lie would never find the reference again. Corner order inside a face is kept: it
        decides how Cycles splits a quad."""
        nv, nf, nc = len(mesh.vertices), len(mesh.polygons), len(mesh.loops)
        self.put(f"mesh {nv} {len(mesh.edges)} {nf} {nc}")
        per = {"POINT": [], "EDGE": [], "FACE": [], "CORNER": []}
        for attr in sorted(mesh.attributes, key=lambda a: a.name):
            if attr.name.startswith((".select", ".corner_", ".edge_verts")):
                continue  # selection; topology (below)
            self.put(f"attribute {attr.name!r} {attr.domain} {attr.data_type}")
            if attr.domain in per:
                per[attr.domain].append(_attribute_bytes(attr))
            else:
                self.put_bytes(f"attribute {attr.name!r}", _attribute_bytes(attr).tobytes())
        if nc == 0:
            return
        corner_vert = np.empty(nc, np.int32)
        mesh.attributes[".corner_vert"].data.foreach_get("value", corner_vert)
        corner = np.concatenate([a[corner_vert] for a in per["POINT"]] + per["CORNER"], axis=1)
        starts = np.empty(nf, np.int32)
        totals = np.empty(nf, np.int32)
        mesh.polygons.foreach_get("loop_start", starts)
        mesh.polygons.foreach_get("loop_total", totals)
        width = int(totals.max()) if nf else 0
        cols = [totals.astype("<i4").view(np.uint8).reshape(nf, 4)] + per["FACE"]
        for k in range(width):  # corner k of every face (zeros past a face's end)
            rows = np.zeros((nf, corner.shape[1]), np.uint8)
            has = totals > k
            rows[has] = corner[starts[has] + k]
            cols.append(rows)
        self.put_bytes("faces", _sorted_rows(np.concatenate(cols, axis=1)))
        if len(mesh.edges) and per["EDGE"]:
            ends = np.empty(2 * len(mesh.edges), np.int32)
            mesh.attributes[".edge_verts"].data.foreach_get("value", ends)
            pos = per["POINT"][0] if per["POINT"] else np.zeros((nv, 0), np.uint8)
            a, b = pos[ends[0::2]], pos[ends[1::2]]
            swap = _sorted_rows_order_pair(a, b)
            lo = np.where(swap[:, None], b, a)
            hi = np.where(swap[:, None], a, b)
            self.put_bytes("edges", _sorted_rows(np.concatenate([lo, hi] + per["EDGE"], axis=1)))

    def special_Text(self, text):
        self.put(f"text={text.as_string()!r}")

    def special_Volume(self, vol):
        self.put(f"frame_files={vol.is_sequence if hasattr(vol, 'is_sequence') else ''}")


def _attribute_bytes(attr):
    """An attribute's values as one row of bytes per element: (n, bytes) uint8."""
    data = attr.data
    n = len(data)
    if n == 0:
        return np.zeros((0, 0), np.uint8)
    cols = []
    for prop in data[0].bl_rna.properties:
        t = prop.type
        if prop.identifier == "rna_type":
            continue
        if t in NUMERIC:
            size = int(np.prod([d for d in prop.array_dimensions if d])) if prop.is_array else 1
            arr = np.empty(n * size, {"FLOAT": np.float32, "INT": np.int32, "BOOLEAN": np.bool_}[t])
            data.foreach_get(prop.identifier, arr)
            cols.append(arr.reshape(n, -1).view(np.uint8).reshape(n, -1))
        elif t == "STRING":  # rare: as fixed-width UTF-8
            vals = [getattr(d, prop.identifier).encode() for d in data]
            width = max(map(len, vals)) + 1
            cols.append(np.frombuffer(b"".join(v.ljust(width, b"\0") for v in vals), np.uint8).reshape(n, width))
    return np.ascontiguousarray(np.concatenate(cols, axis=1)) if cols else np.zeros((n, 0), np.uint8)


def _sorted_rows(rows):
    """The bytes of a uint8 matrix with its rows sorted (order-independent)."""
    rows = np.ascontiguousarray(rows)
    if rows.size == 0:
        return rows.shape[0].to_bytes(8, "little")
    view = rows.view(np.dtype((np.void, rows.shape[1]))).ravel()
    return rows.shape[1].to_bytes(8, "little") + np.sort(view).tobytes()


def _sorted_rows_order_pair(a, b):
    """Per row, whether b's bytes sort before a's (to write an edge's ends in one order)."""
    if a.shape[1] == 0:
        return np.zeros(len(a), bool)
    differ = a != b
    first = np.argmax(differ, axis=1)
    rows = np.arange(len(a))
    return differ.any(axis=1) & (b[rows, first] < a[rows, first])


def _plain(value):
    """A nested tuple of Python numbers for RNA arrays and mathutils values (exact floats)."""
    if hasattr(value, "__len__") and not isinstance(value, str):
        return tuple(_plain(v) for v in value)
    return value


def fingerprint(scene, kind, lines=None):
    """The key of the Cycles render of `scene` as things are now: 32 hex digits. `kind` names
    what is returned from the render (an RGBA image, a multilayer file's passes).
    `lines`: a list to append the walk to (to see why two keys differ)."""
    w = _Walker()
    debug = os.environ.get("PATHLIGHT_CYCLES_REFS_DEBUG")  # a folder: each walk as KEY.txt
    w.lines = lines if lines is not None or not debug else []
    w.put(f"pathlight-cycles-ref {FINGERPRINT_VERSION} {kind}")
    w.put(f"bpy {bpy.app.version_string} {bpy.app.build_hash!r} {bpy.app.build_commit_date!r}")
    w.put(f"scene {scene.name_full!r} frame {scene.frame_current} {scene.frame_subframe!r}")
    w.put(f"view_layer {bpy.context.view_layer.name!r}" if bpy.context.view_layer else "view_layer None")
    for coll_name in ID_COLLECTIONS:
        coll = getattr(bpy.data, coll_name, None)
        if coll is None:
            continue
        for idb in sorted(coll, key=lambda i: (i.name_full,)):
            if isinstance(idb, bpy.types.Image) and idb.type in ("RENDER_RESULT", "COMPOSITING"):
                continue  # the output of earlier renders
            w.walk_id(idb)
    key = w.h.hexdigest()[:32]
    if debug and w.lines is not None:
        Path(debug).mkdir(parents=True, exist_ok=True)
        (Path(debug) / f"{key}.txt").write_text("\n".join(w.lines))
    return key


# -- storage -------------------------------------------------------------------------------------

def mode():
    value = os.environ.get("PATHLIGHT_CYCLES_REFS", "render").strip().lower() or "render"
    if value not in MODES:
        raise ValueError(f"PATHLIGHT_CYCLES_REFS={value!r}: expected one of {', '.join(MODES)}")
    return value


def _pack(arrays):
    """{name: float32 array} -> bytes: a JSON header line, then each array's bytes shuffled
    (byte planes: the exponents compress well) and deflated. RGBA whose alpha is all 1 keeps RGB."""
    header, blobs = [], []
    for name, arr in sorted(arrays.items()):
        arr = np.ascontiguousarray(arr, np.float32)
        entry = {"name": name, "shape": list(arr.shape)}
        if arr.ndim == 3 and arr.shape[-1] == 4 and np.all(arr[..., 3] == 1.0):
            arr = np.ascontiguousarray(arr[..., :3])
            entry["alpha_one"] = True
        shuffled = arr.view(np.uint8).reshape(-1, 4).T.tobytes()
        blob = zlib.compress(shuffled, 9)
        entry["bytes"] = len(blob)
        header.append(entry)
        blobs.append(blob)
    return (b"PLCYREF1\n" + json.dumps(header).encode() + b"\n" + b"".join(blobs))


def _unpack(data):
    magic, header, rest = data.split(b"\n", 2)
    if magic != b"PLCYREF1":
        raise ValueError("not a Pathlight Cycles reference")
    out, pos = {}, 0
    for entry in json.loads(header):
        blob = rest[pos:pos + entry["bytes"]]
        pos += entry["bytes"]
        shape = list(entry["shape"])
        if entry.get("alpha_one"):
            shape[-1] = 3
        planes = np.frombuffer(zlib.decompress(blob), np.uint8).reshape(4, -1)
        arr = np.ascontiguousarray(planes.T).view(np.float32).reshape(shape)
        if entry.get("alpha_one"):
            arr = np.concatenate([arr, np.ones(shape[:-1] + [1], np.float32)], axis=-1)
        out[entry["name"]] = arr
    return out


def ref_path(key):
    return REFS_DIR / f"{key}.plref"


def load(key):
    path = ref_path(key)
    try:
        return _unpack(path.read_bytes())
    except FileNotFoundError:
        return None


def store(key, arrays):
    _write_atomic(ref_path(key), _pack(arrays))


def _write_atomic(path, data):
    """A temporary file in the same folder, then a rename: two xdist workers may store the same
    key at once, and a reader never sees half a file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def record(key, what, start):
    """Note the key as used by this process (for `build.py test --refs prune`), how, and the CPU
    and wall seconds since `start` (a _clock()): "KEY hit|stored|checked CPU WALL TEST"."""
    cpu, wall = (a - b for a, b in zip(_clock(), start))
    try:
        USED_DIR.mkdir(parents=True, exist_ok=True)
        worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
        test = os.environ.get("PYTEST_CURRENT_TEST", "").rsplit(" ", 1)[0]
        session = os.environ.get("PATHLIGHT_REFS_SESSION", "0")  # tests/conftest.py sets it
        with open(USED_DIR / f"{session}-{worker}-{os.getpid()}.txt", "a") as f:
            f.write(f"{key} {what} {cpu:.3f} {wall:.3f} {test}\n")
    except OSError:
        pass


def _clock():
    """(CPU seconds of this process, all its threads: Cycles renders on every core; wall seconds)."""
    return time.process_time(), time.perf_counter()


def _mode_and_key(scene, kind, refs):
    """(this call's mode, the key or None when the store is not used, the start clock). `refs`:
    the call's own mode; PATHLIGHT_CYCLES_REFS=render or refresh overrides it."""
    env = mode()
    m = env if (refs is None or env in ("render", "refresh")) else refs
    if getattr(scene.cycles, "time_limit", 0.0) > 0.0:
        m = "render"  # the image depends on the machine's speed: never stored
    start = _clock()
    return m, (None if m == "render" else _key_or_none(scene, kind)), start


def cached_file(scene, kind, path, render, read, refs=None):
    """Like cached(), for a render that writes a file at `path` (a multilayer EXR, headers and
    all): render() writes it, read(path) -> {name: float32 array} compares two of them. A hit
    copies the stored file to `path`."""
    m, key, start = _mode_and_key(scene, kind, refs)
    if key is None:
        return render()
    stored = ref_path(key).with_suffix(Path(path).suffix)
    if m == "use" and stored.is_file():
        shutil.copyfile(stored, path)
        record(key, "hit", start)
        return None
    render()
    if m == "check" and stored.is_file():
        compare(key, read(stored), read(path))
        record(key, "checked", start)
        return None
    _write_atomic(stored, Path(path).read_bytes())
    record(key, "stored", start)
    return None


class ReferenceMismatch(AssertionError):
    pass


def compare(key, stored, fresh):
    """Fail when a fresh Cycles render differs from its stored reference beyond float noise."""
    if sorted(stored) != sorted(fresh):
        raise ReferenceMismatch(f"Cycles reference {key}: channels {sorted(stored)} != {sorted(fresh)}")
    for name in stored:
        a, b = stored[name], fresh[name]
        if a.shape != b.shape:
            raise ReferenceMismatch(f"Cycles reference {key} {name}: shape {a.shape} != {b.shape}")
        diff = np.abs(a.astype(np.float64) - b)
        bad = ~(diff <= 1e-5 * np.maximum(1.0, np.abs(b))) & ~(np.isnan(a) & np.isnan(b))
        if bad.any():
            raise ReferenceMismatch(
                f"stored Cycles reference {ref_path(key).name} ({name}) differs from a fresh Cycles "
                f"render: {int(bad.sum())} values, max |diff| {np.nanmax(diff):.3g}. The fingerprint "
                "misses something this render reads, or this bpy renders differently.")


def _key_or_none(scene, kind):
    """The key, or None with a warning when the walk fails on data it does not know yet (the
    test then renders with Cycles, uncached, as before)."""
    try:
        return fingerprint(scene, kind)
    except Exception as exc:
        import traceback
        import warnings
        where = traceback.extract_tb(exc.__traceback__)[-1]
        warnings.warn(f"Cycles reference key failed ({type(exc).__name__}: {exc}, line {where.lineno}); "
                      "rendering with Cycles without the stored references")
        return None


def cached(scene, kind, render, refs=None):
    """render() -> {name: float32 array}, through the stored references. `refs`: this call's
    mode ("check" for the tests that verify the cache every run); PATHLIGHT_CYCLES_REFS=render
    or refresh overrides it."""
    m, key, start = _mode_and_key(scene, kind, refs)
    if key is None:
        return render()
    if m == "use":
        stored = load(key)
        if stored is not None:
            record(key, "hit", start)
            return stored
    fresh = render()
    if m == "check":
        stored = load(key)
        if stored is not None:
            compare(key, stored, fresh)
            record(key, "checked", start)
            return fresh
    store(key, fresh)
    record(key, "stored", start)
    return fresh
