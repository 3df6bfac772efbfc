"""Input nodes: texture coordinates, UV maps, attributes, geometry, light path, object and
curves info, and the nodes that trace rays from the shading point (AO, Bevel, Wireframe)
(a ShaderCompiler mixin)."""

import numpy as np

from .uv_sets import MAX_OBJECT_ATTRIBUTES, MAX_UV_SETS
from .values import ZERO, Val, const_color, const_float, const_vector


def _rna_value(holder, name):
    """A property of `holder` as Cycles reads an attribute from it (lookup_property): a number or
    boolean as (v, v, v, 1), a float array of 1-4 as (x, y, z, w) padded with (0, 0, 0, 1);
    None where it has none of those."""
    try:
        v = holder.path_resolve(name)
    except (ValueError, TypeError, AttributeError):
        return None
    if isinstance(v, bool):
        v = float(v)
    if isinstance(v, (int, float)):
        return (float(v),) * 3 + (1.0,)
    try:
        vals = list(v)
    except TypeError:
        return None
    if not 1 <= len(vals) <= 4 or not all(isinstance(x, float) for x in vals):
        return None
    out = [0.0, 0.0, 0.0, 1.0]
    out[:len(vals)] = vals
    return tuple(out)


def view_layer_attribute(holders, name):
    """A View Layer attribute: looked up in the view layer, its scene and world, in that order;
    in each a custom property before a built-in (RNA path) one, as Blender does."""
    if not name:
        return None
    for holder in holders:
        for path in (f'["{name}"]', name):
            v = _rna_value(holder, path)
            if v is not None:
                return v
    return None


class InputNodes:
    """Translators of the Input nodes (ShaderCompiler mixin)."""

    def uv(self, name, what):
        k = self.uv_sets.index(name)
        if k is None:
            self.problem(f"{what}: more than {MAX_UV_SETS} UV maps in the scene (UV map "
                         f"'{name}' reads as the first)")
            k = 0
        self.uv_used[k] = name or ""
        return k

    def uv_value(self, name, what):
        """Val of the UV coordinates of a UV map (one "uv" op per set)."""
        k = self.uv(name, what)
        key = ("uv", k, self.bump_state)
        if key not in self.cache:
            extra = (self.bump_state,) if self.bump_state else ()
            self.cache[key] = self.emit("vector", "uv", k, *extra)
        return self.cache[key]

    def attribute_value(self, kind, name, output, what):
        """Val of a mesh attribute's output ("COLOR", "FAC" or "ALPHA"): kind "attr" (by name)
        or "color" (a colour attribute; "" = the mesh's render colour attribute)."""
        k = self.uv_sets.index((kind, name))
        if k is None:
            self.problem(f"{what}: more than {MAX_UV_SETS} UV maps and attributes in the scene "
                         "(reads 0)")
            return ZERO if output != "COLOR" else const_color((0, 0, 0, 0))
        self.uv_used[k] = (kind, name)
        key = ("attribute", k, output)
        if key not in self.cache:
            self.cache[key] = self.emit("float" if output != "COLOR" else "color", "attribute", k,
                                        output)
        return self.cache[key]

    def color_attribute(self, node, out, ctx):
        """Color Attribute: a colour attribute of the mesh (its render one when unnamed)."""
        output = "ALPHA" if out.identifier == "Alpha" else "COLOR"
        return self.attribute_value("color", node.layer_name, output, f"'{node.name}'")

    def attribute_node(self, node, out, ctx):
        """Attribute: a geometry attribute of the mesh by name (any domain but edges, any
        type: floats read as grey, 2D vectors with z = 0), a View Layer attribute (a
        constant of the render), or an Object / Instancer attribute (a constant of each
        instance: a per-instance slot that the export resolves)."""
        if node.attribute_type == 'VIEW_LAYER':
            v = view_layer_attribute(self.view_layer_ids, node.attribute_name) or (0.0, 0.0, 0.0, 0.0)
            if out.identifier == "Fac":
                return const_float(sum(v[:3]) / 3.0)
            if out.identifier == "Alpha":
                return const_float(v[3])
            if out.identifier == "Vector":
                return const_vector(v[:3])
            return const_color(v[:3] + (1.0,))
        if node.attribute_type in ('OBJECT', 'INSTANCER'):
            return self.object_attribute(node, out)
        if node.attribute_type != 'GEOMETRY':
            self.problem(f"'{node.name}': {node.attribute_type.lower().replace('_', ' ')} "
                         "attributes are not supported (0)")
            return ZERO if out.identifier in ("Fac", "Alpha") else const_color((0, 0, 0, 1))
        if not node.attribute_name:
            return ZERO if out.identifier in ("Fac", "Alpha") else const_color((0, 0, 0, 1))
        output = {"Fac": "FAC", "Alpha": "ALPHA"}.get(out.identifier, "COLOR")
        if self.volume_grids is not None:  # a volume object: the grid of that name, else 0
            v = self.grid_value(node.attribute_name, output, node)
            if v is None:
                return ZERO if output != "COLOR" else const_color((0, 0, 0, 0))
            return Val("vector", reg=v.reg) if out.identifier == "Vector" else v
        v = self.attribute_value("attr", node.attribute_name, output, f"'{node.name}'")
        return Val("vector", reg=v.reg) if out.identifier == "Vector" else v

    def grid_value(self, name, output, node):
        """Val of a volume object's grid `name` ("COLOR", "FAC" or "ALPHA" as the Attribute
        node's outputs), or None where this is no volume object or it has no such grid."""
        if self.volume_grids is None or not name or name not in self.volume_grids:
            return None
        grid_id, channels = self.volume_grids[name]
        if output == "FAC" and channels == 3:
            self.problem(f"'{node.name}': the vector grid '{name}' is read as a float (the mean of "
                         "its components, as Cycles)")
        interp = self.volume_interpolation if self.volume_interpolation in ('CLOSEST', 'CUBIC') else 'LINEAR'
        key = ("volume_grid", grid_id, output, interp)
        if key not in self.cache:
            self.cache[key] = self.emit("float" if output != "COLOR" else "color", "volume_grid",
                                        grid_id, output, interp)
        return self.cache[key]

    def volume_info(self, node, out, ctx):
        """Volume Info: a volume object's grids color, density, flame, temperature (0 where
        missing, and on other objects, as Cycles)."""
        name = {"Color": "color", "Density": "density", "Flame": "flame",
                "Temperature": "temperature"}.get(out.identifier)
        output = "COLOR" if name == "color" else "FAC"
        v = self.grid_value(name, output, node)
        if v is None:
            return const_color((0, 0, 0, 1)) if output == "COLOR" else ZERO
        return v

    def object_attribute(self, node, out):
        """Val of an Object / Instancer attribute: its per-instance slot read by the core (a
        name found nowhere reads 0, alpha too, as Cycles)."""
        zero = ZERO if out.identifier in ("Fac", "Alpha") else const_color((0, 0, 0, 0))
        if not node.attribute_name:
            return zero
        slot = self.uv_sets.object_attribute_slot(node.attribute_type, node.attribute_name)
        if slot is None:
            self.problem(f"'{node.name}': more than {MAX_OBJECT_ATTRIBUTES} object and instancer "
                         "attributes in the scene (reads 0)")
            return zero
        output = {"Fac": "FAC", "Alpha": "ALPHA"}.get(out.identifier, "COLOR")
        key = ("object_attribute", slot, output)
        if key not in self.cache:
            self.cache[key] = self.emit("float" if output != "COLOR" else "color",
                                        "object_attribute", slot, output)
        v = self.cache[key]
        return Val("vector", reg=v.reg) if out.identifier == "Vector" else v

    def object_coords(self, which):
        """Val of the object-space ("object") or texture-space ("generated") position."""
        key = (which, self.bump_state)
        if key not in self.cache:
            extra = self._at_offset() if which == "object" else \
                ((self.bump_state,) if self.bump_state else ())
            self.cache[key] = self.emit("vector", which, *extra)
        return self.cache[key]

    def position(self):
        """Val of the world position (at the current bump offset)."""
        key = ("position", self.bump_state)
        if key not in self.cache:
            self.cache[key] = self.emit("vector", "position", *self._at_offset())
        return self.cache[key]

    def _at_offset(self):
        """Position and Object ops' operand: the bump offset, plus 4 (the core's kUndisplaced)
        inside the bump of a truly displaced material ('BOTH'), which Cycles evaluates on the
        undisplaced surface."""
        sub = self.bump_state | (4 if self.undisplaced else 0)
        return (sub,) if sub else ()

    def camera_coords(self, which):
        """Texture Coordinate's Camera or Window (at the current bump offset)."""
        key = ("camera_coords", which, self.bump_state)
        if key not in self.cache:
            extra = (self.bump_state,) if self.bump_state else ()
            self.cache[key] = self.emit("vector", "camera_coords", which, *extra)
        return self.cache[key]

    def other_object_coords(self, ob):
        """Texture Coordinate's Object output with its Object set: the point in that object's
        space, as Cycles (its evaluated world matrix, inverted, applied to the position)."""
        if self.depsgraph is not None:
            try:
                ob = ob.evaluated_get(self.depsgraph)
            except (RuntimeError, ReferenceError):
                pass  # not in the depsgraph: the original's matrix
        m = np.array(ob.matrix_world, dtype=np.float64)
        try:
            inv = np.linalg.inv(m)
        except np.linalg.LinAlgError:
            inv = np.zeros((4, 4))  # a scaled-flat object: 0 (Cycles nudges the diagonal)
        if not np.all(np.isfinite(inv)):
            inv = np.zeros((4, 4))
        return self.emit("vector", "mapping", self.reg(self.position()),
                         np.ascontiguousarray(inv[:3, :4], np.float32))

    def instancer_coords(self, node, oid):
        """Texture Coordinate's UV or Generated From Instancer: the instance's coordinates on
        its instancer (Blender's dupli uv and orco), constant per instance, 0 for objects that
        are no instance, as Cycles."""
        slot = self.uv_sets.object_attribute_slot("DUPLI", oid.lower())
        if slot is None:
            self.problem(f"'{node.name}': more than {MAX_OBJECT_ATTRIBUTES} object and instancer "
                         f"attributes in the scene ({oid} from instancer reads 0)")
            return const_vector((0, 0, 0))
        key = ("object_attribute", slot, "COLOR")
        if key not in self.cache:
            self.cache[key] = self.emit("color", "object_attribute", slot, "COLOR")
        return Val("vector", reg=self.cache[key].reg)

    def tex_coord(self, node, oid):
        if getattr(self, "background", False):
            return self.background_coord(node, oid)
        if node.from_instancer and oid in ("UV", "Generated"):
            return self.instancer_coords(node, oid)
        if oid == "UV":
            return self.uv_value("", f"'{node.name}'")
        if oid == "Object" and node.object is not None:
            return self.other_object_coords(node.object)
        if oid in ("Object", "Generated"):
            return self.object_coords(oid.lower())
        if oid == "Normal":
            return self.emit("vector", "object_normal")
        if oid == "Reflection":
            return self.emit("vector", "geometry", "REFLECTION")
        if oid in ("Camera", "Window"):
            return self.camera_coords(oid.upper())
        self.problem(f"'{node.name}': {oid} coordinates are not supported (0)")
        return const_vector((0, 0, 0))

    def background_coord(self, node, oid):
        """Texture Coordinate in a world (Cycles' svm_node_tex_coord without an object: P is
        the ray's direction, N = -P): Generated, Object (without an object) and Reflection the
        direction, Normal -direction, Camera and Window the point camera + direction, UV 0."""
        if oid == "Object" and node.object is not None:
            return self.other_object_coords(node.object)
        if oid in ("Generated", "Object", "Reflection"):
            return self.position()
        if oid == "Normal":
            return self.emit("vector", "normal")
        if oid in ("Camera", "Window"):
            return self.emit("vector", "background_camera", oid.upper())
        if oid != "UV":
            self.problem(f"'{node.name}': {oid} coordinates are not supported (0)")
        return const_vector((0, 0, 0))

    def fresnel_node(self, node, out, ctx):
        ior = self.input(node, "IOR", ctx, "float")
        normal = self.normal(node, ctx)
        return self.emit("float", "fresnel", self.reg(ior),
                         None if normal is None else self.reg(normal))

    def layer_weight(self, node, out, ctx):
        blend = self.input(node, "Blend", ctx, "float")
        normal = self.normal(node, ctx)
        which = "FACING" if out.identifier == "Facing" else "FRESNEL"
        return self.emit("float", "layer_weight", self.reg(blend),
                         None if normal is None else self.reg(normal), which)

    _GEOMETRY = {"True Normal": "TRUE_NORMAL", "Incoming": "INCOMING",
                 "Parametric": "PARAMETRIC", "Backfacing": "BACKFACING"}

    def light_path(self, node, out, ctx):
        """Light Path: every output from the core's path state, as Cycles'."""
        which = out.identifier.upper().replace(" ", "_")
        if which not in self._LIGHT_PATH:
            self.problem(f"'{node.name}': output {out.name} is not supported (0)")
            return ZERO
        return self.emit("float", "light_path", which)

    _LIGHT_PATH = {"IS_CAMERA_RAY", "IS_SHADOW_RAY", "IS_DIFFUSE_RAY", "IS_GLOSSY_RAY",
                   "IS_SINGULAR_RAY", "IS_REFLECTION_RAY", "IS_TRANSMISSION_RAY",
                   "IS_VOLUME_SCATTER_RAY", "RAY_LENGTH",
                   "RAY_DEPTH", "DIFFUSE_DEPTH", "GLOSSY_DEPTH", "TRANSPARENT_DEPTH",
                   "TRANSMISSION_DEPTH"}

    _OBJECT_INFO = {"Location": ("vector", "LOCATION"), "Color": ("color", "COLOR"),
                    "Alpha": ("float", "ALPHA"), "Object Index": ("float", "OBJECT_INDEX"),
                    "Random": ("float", "RANDOM")}

    def object_info(self, node, out, ctx):
        """Object Info: the hit instance's location, colour, alpha, pass index and random
        number (per instance in the core); Material Index is this material's pass index."""
        if out.identifier == "Material Index":
            return const_float(float(self.material_index))
        kind, which = self._OBJECT_INFO.get(out.identifier, (None, None))
        if kind is None:
            self.problem(f"'{node.name}': output {out.name} is not supported (0)")
            return ZERO
        return self.emit(kind, "object_info", which)

    # Particle Info outputs: (the per-instance slot's name, a vector).
    _PARTICLE_INFO = {"Index": ("index", False), "Random": ("random", False), "Age": ("age", False),
                      "Lifetime": ("lifetime", False), "Location": ("location", True), "Size": ("size", False),
                      "Velocity": ("velocity", True), "Angular Velocity": ("angular_velocity", True)}

    def particle_info(self, node, out, ctx):
        """Particle Info: the hit instance's particle, as Cycles' svm_node_particle_info, in a
        per-instance slot (export.object_attributes: zeros and the random number of index 0
        off particle instances, as Cycles' dummy particle). Scalars read the slot's alpha."""
        name, vector = self._PARTICLE_INFO.get(out.identifier, (None, False))
        if name is None:
            self.problem(f"'{node.name}': output {out.name} is not supported (0)")
            return ZERO
        slot = self.uv_sets.object_attribute_slot("PARTICLE", name)
        if slot is None:
            self.problem(f"'{node.name}': more than {MAX_OBJECT_ATTRIBUTES} object, instancer and "
                         "particle attributes in the scene (reads 0)")
            return ZERO
        output = "COLOR" if vector else "ALPHA"
        key = ("object_attribute", slot, output)
        if key not in self.cache:
            self.cache[key] = self.emit("color" if vector else "float", "object_attribute", slot, output)
        v = self.cache[key]
        return Val("vector", reg=v.reg) if vector else v

    _CURVES_INFO = {"Is Strand": ("float", "IS_STRAND"), "Intercept": ("float", "INTERCEPT"),
                    "Length": ("float", "LENGTH"), "Thickness": ("float", "THICKNESS"),
                    "Tangent Normal": ("vector", "TANGENT_NORMAL"), "Random": ("float", "RANDOM")}

    def curves_info(self, node, out, ctx):
        """Curves Info: what the hit strand's geometry says (zeros off curves, as Cycles)."""
        kind, which = self._CURVES_INFO.get(out.identifier, (None, None))
        if kind is None:
            self.problem(f"'{node.name}': output {out.name} is not supported (0)")
            return ZERO
        return self.emit(kind, "curves_info", which)

    _POINT_INFO = {"Position": ("vector", "POSITION"), "Radius": ("float", "RADIUS"),
                   "Random": ("float", "RANDOM")}

    def point_info(self, node, out, ctx):
        """Point Info: the hit point's centre, radius and random number (zeros off points, as
        Cycles)."""
        kind, which = self._POINT_INFO.get(out.identifier, (None, None))
        if kind is None:
            self.problem(f"'{node.name}': output {out.name} is not supported (0)")
            return ZERO
        return self.emit(kind, "point_info", which)

    def tangent_node(self, node, out, ctx):
        """Tangent: radial around an object axis (from the generated coordinates) or a UV
        map's tangent (per triangle from its uvs, where Cycles interpolates MikkTSpace's)."""
        if node.direction_type == 'UV_MAP':
            k = self.uv(node.uv_map, f"'{node.name}'")
            return self.emit("vector", "tangent", "UV_MAP", k)
        return self.emit("vector", "tangent", node.axis, 0)

    def ambient_occlusion(self, node, out, ctx):
        """Ambient Occlusion: rays traced from the shading point as Cycles' (Samples,
        Distance, Inside, Only Local); Color is AO times the Color input."""
        color = self.reg(self.input(node, "Color", ctx, "color"))
        (dist,) = self._texture_floats(node, ("Distance",), ctx)
        normal = self.normal(node, ctx)
        which = "AO" if out.identifier == "AO" else "COLOR"
        return self.emit("float" if which == "AO" else "color", "ambient_occlusion", color, dist,
                         None if normal is None else self.reg(normal), int(node.samples),
                         bool(node.inside), bool(node.only_local), which)

    def bevel(self, node, out, ctx):
        """Bevel: the instance's smooth normals within Radius, found by traced rays as Cycles'
        (Samples); a linked Normal keeps its own bend."""
        (radius,) = self._texture_floats(node, ("Radius",), ctx)
        normal = self.normal(node, ctx)
        return self.emit("vector", "bevel", radius, None if normal is None else self.reg(normal),
                         int(node.samples))

    def wireframe(self, node, out, ctx):
        """Wireframe: 1 near the triangles' edges (Size in world units, or in pixels)."""
        (size,) = self._texture_floats(node, ("Size",), ctx)
        extra = (self.bump_state,) if self.bump_state else ()
        return self.emit("float", "wireframe", size, bool(node.use_pixel_size), *extra)


    _CAMERA_DATA = {"View Vector": ("vector", "VIEW_VECTOR"), "View Z Depth": ("float", "VIEW_Z_DEPTH"),
                    "View Distance": ("float", "VIEW_DISTANCE")}

    def camera_data(self, node, out, ctx):
        """Camera Data: the shading point in the camera's space, as Cycles' svm_node_camera
        (its direction, z and length; not moved by Bump offsets, as Cycles)."""
        kind, which = self._CAMERA_DATA.get(out.identifier, (None, None))
        if kind is None:
            self.problem(f"'{node.name}': output {out.name} is not supported (0)")
            return ZERO
        key = ("camera_data", which)
        if key not in self.cache:
            self.cache[key] = self.emit(kind, "camera_data", which)
        return self.cache[key]


# Handlers of ShaderCompiler._VALUE_NODES (node type -> function of compiler, node, output
# socket, group context).
    def light_falloff(self, node, out, ctx):
        """Cycles' Light Falloff (svm_node_light_falloff): Strength times the ray's length to
        the power 0 (Quadratic), 1 (Linear) or 2 (Constant), smoothed by Smooth; in a light's
        tree the length is the light sample's distance."""
        strength = self.input(node, "Strength", ctx, "float")
        smooth = self.input(node, "Smooth", ctx, "float")
        which = {"Linear": "LINEAR", "Constant": "CONSTANT"}.get(out.identifier, "QUADRATIC")
        return self.emit("float", "light_falloff", self.reg(strength), self.reg(smooth), which)


VALUE_NODES = {
    'FRESNEL': InputNodes.fresnel_node, 'LAYER_WEIGHT': InputNodes.layer_weight,
    'LIGHT_PATH': InputNodes.light_path, 'OBJECT_INFO': InputNodes.object_info,
    'HAIR_INFO': InputNodes.curves_info, 'POINT_INFO': InputNodes.point_info, 'VERTEX_COLOR': InputNodes.color_attribute,
    'ATTRIBUTE': InputNodes.attribute_node, 'VOLUME_INFO': InputNodes.volume_info, 'TANGENT': InputNodes.tangent_node,
    'AMBIENT_OCCLUSION': InputNodes.ambient_occlusion, 'BEVEL': InputNodes.bevel,
    'WIREFRAME': InputNodes.wireframe, 'PARTICLE_INFO': InputNodes.particle_info,
    'LIGHT_FALLOFF': InputNodes.light_falloff, 'CAMERA': InputNodes.camera_data,
}
