"""The Attribute node's Object and Instancer attributes: per depsgraph instance, the RGBA value
of each scene-wide slot (shader.UvSets.object_attributes), looked up as Cycles 4.5 does
(BKE_object_dupli_find_rgba_attribute): for Instancer, on an instance, the particle settings,
the geometry-nodes instance attribute (of nested instances, the innermost level that has
the name: Cycles' find_geonode_attribute_rgba), then the instancing object; then the object
and its data. In each holder a custom property of that name before an RNA path ("color",
"location", "data.foo", '["prop"]'). A name found nowhere reads (0, 0, 0, 0). Also the
Texture Coordinate node's From Instancer coordinates (kind "DUPLI"): an instance's uv and orco
on its instancer, as Cycles' dupli_uv and dupli_generated (0.5 orco - 0.5), 0 elsewhere.

bpy gives a depsgraph instance no instance attributes: they are read from the instancer's
evaluated geometry (Object.evaluated_geometry(), each level's instances as a point cloud),
followed down by the instance's persistent_id, which Blender builds per nesting level from the
instances' unique ids (BKE duplilist make_dupli). An instance of a collection-instance empty
that instances a geometry-nodes object has the empty as parent: its geometry-nodes levels are
not followed (the empty's and the object's own properties still are)."""

import numpy as np

from .mesh import _attribute_rgba as attribute_rgba  # Cycles' conversions to RGBA

_UNUSED_ID = 2147483647  # persistent_id entries past the instance's nesting depth


def _hash_uint2_to_float(a, b):
    from ..core import get_core
    return get_core().hash_uint2_to_float(a, b)


def _rgba(v):
    """A property value as Cycles converts it (find_property_rgba): a number or boolean as
    (v, v, v, 1), a float or int array of 1-4 as (x, y, z, w) padded with (0, 0, 0, 1); None
    for anything else (strings, pointers, boolean arrays, longer arrays)."""
    if isinstance(v, bool):
        v = float(v)
    if isinstance(v, (int, float)):
        return (float(v),) * 3 + (1.0,)
    if isinstance(v, str):
        return None
    try:
        n = len(v)
    except TypeError:
        return None
    if not 1 <= n <= 4:
        return None
    vals = list(v)
    if any(isinstance(x, bool) for x in vals) or not (all(isinstance(x, float) for x in vals) or
                                                        all(isinstance(x, int) for x in vals)):
        return None
    out = [0.0, 0.0, 0.0, 1.0]
    out[:n] = (float(x) for x in vals)
    return tuple(out)


def property_rgba(holder, name):
    """The value of `name` on an ID (or None where it has no usable one): its custom property
    of that name if it has one (even one of an unusable type ends the search here, as
    Cycles), else the RNA path."""
    if holder is None:
        return None
    try:
        if name in holder.keys():
            return _rgba(holder[name])
    except (TypeError, AttributeError):
        pass
    try:
        v = holder.path_resolve(name)
    except (ValueError, TypeError, AttributeError):
        return None
    return _rgba(v)


# Geometry components that make an instance of their own inside an instanced geometry set, in
# the order Blender numbers them (make_duplis_geometry_set_impl); on the instancing object
# itself, the component of the object's own type is the object, not an instance.
_COMPONENTS = (("mesh", ("MESH",)), ("volume", ("VOLUME",)), ("curves", ("CURVES", "CURVE", "FONT")),
               ("pointcloud", ("POINTCLOUD",)), ("grease_pencil", ("GREASEPENCIL",)))


class _Level:
    """One geometry set of an instancer's geometry-nodes instance tree (read lazily, kept for
    one export): its instances (as bpy's point cloud of them), their ids and references, and
    the instance attributes read so far."""

    def __init__(self, geometry, own_type=None):
        self.geometry = geometry  # keeps the point cloud alive
        self.components = sum(1 for name, types in _COMPONENTS
                              if own_type not in types and getattr(geometry, name, None) is not None)
        try:
            self.points = geometry.instances_pointcloud()
        except (AttributeError, RuntimeError):
            self.points = None
        self._ids = self._refs = self._handles = None
        self._children = {}
        self._attrs = {}

    def index_of(self, unique_id):
        """The instance whose persistent id is `unique_id` (Blender's Instances::unique_ids: the
        "id" attribute where there is one, else the index), or None."""
        n = len(self.points.points)
        if self._ids is None:
            self._ids = {}
            attr = self.points.attributes.get("id")
            if attr is not None and attr.data_type == 'INT' and attr.domain == 'POINT':
                ids = np.empty(n, np.int32)
                attr.data.foreach_get("value", ids)
                # The first of equal ids keeps it (Blender renumbers the others at random: they
                # are not found, and only the outer levels' attributes are read).
                self._ids = dict(zip(ids[::-1].tolist(), range(n - 1, -1, -1)))
            else:
                self._ids = False
        if self._ids is False:
            return unique_id if 0 <= unique_id < n else None
        return self._ids.get(unique_id)

    def child(self, index):
        """The _Level of instance `index`'s reference where it is a geometry set, else None
        (an object or collection: its own instances are not this tree's)."""
        if self._handles is None:
            n = len(self.points.points)
            attr = self.points.attributes.get(".reference_index")
            self._handles = np.zeros(n, np.int32)
            if attr is not None and len(attr.data) == n:
                attr.data.foreach_get("value", self._handles)
            try:
                self._refs = list(self.geometry.instance_references())
            except (AttributeError, RuntimeError):
                self._refs = []
        handle = int(self._handles[index])
        if handle not in self._children:
            ref = self._refs[handle] if 0 <= handle < len(self._refs) else None
            self._children[handle] = _Level(ref) if type(ref).__name__ == "GeometrySet" else None
        return self._children[handle]

    def attribute(self, name, index):
        """Instance `index`'s RGBA value of the instance attribute `name`, or None."""
        if name not in self._attrs:
            attr = self.points.attributes.get(name)
            self._attrs[name] = attribute_rgba(attr) if attr is not None and not name.startswith(".") else None
        values = self._attrs[name]
        if values is None or not 0 <= index < len(values):
            return None
        return tuple(float(x) for x in values[index])


class InstanceAttributes:
    """Resolves the slots for depsgraph instances of one export; values shared by every
    instance of the same holders (and geometry-nodes instance attributes) are read once."""

    def __init__(self, slots, frame=0.0):
        self.slots = slots  # the live list of (kind, name): it grows as materials compile
        self._cache = {}
        self._trees = {}  # instancer pointer -> its top _Level (or None: no instances)
        # Particle Info: the scene's frame (ages count from it).
        self.frame = float(frame)
        self._particles = {}  # particle system pointer -> its particles' arrays

    def values(self, instance):
        """float32 (K, 4) for the first K slots (those numbered so far), or None with none."""
        if not self.slots:
            return None
        obj = instance.object
        is_instance = bool(instance.is_instance)
        parent = instance.parent if is_instance else None
        psys = instance.particle_system if is_instance else None
        gn = ()  # (only Instancer attributes read them: Object ones share one entry)
        if parent is not None and psys is None and any(kind == "INSTANCER" for kind, _ in self.slots):
            gn = self._gn_levels(instance, parent)
        key = (obj.as_pointer(), parent.as_pointer() if parent is not None else 0,
               psys.as_pointer() if psys is not None else 0,
               tuple((id(level), i) for level, i in gn), len(self.slots))
        out = self._cache.get(key)
        if out is None:
            out = np.array([self._value(kind, name, obj, parent, psys, gn)
                            for kind, name in self.slots], np.float32)
            self._cache[key] = out
        dupli = [(i, name) for i, (kind, name) in enumerate(self.slots) if kind == "DUPLI"]
        particle = [(i, name) for i, (kind, name) in enumerate(self.slots) if kind == "PARTICLE"]
        if dupli or particle:  # per instance, not shared: each particle sits elsewhere on its emitter
            out = out.copy()
            for i, name in dupli:
                out[i] = self._dupli(instance, name, is_instance)
            if particle:
                data = self._particle(psys, instance.persistent_id[0] if psys is not None else -1)
                for i, name in particle:
                    out[i] = data[name]
        return out

    _PARTICLE_ARRAYS = (("birth_time", 1), ("lifetime", 1), ("location", 3), ("size", 1),
                        ("velocity", 3), ("angular_velocity", 3))

    def _particle(self, psys, index):
        """Particle Info's values (RGBA each; scalars in all four) for particle `index` of psys,
        as Cycles' sync_dupli_particle: age = frame - birth time. Off particles (no system,
        an index past its particles: children) Cycles reads its dummy particle 0: zeros, and the
        random number of index 0."""
        arrays = None
        if psys is not None and index >= 0:
            key = psys.as_pointer()
            if key not in self._particles:
                n = len(psys.particles)
                arrays = {}
                for name, width in self._PARTICLE_ARRAYS:
                    a = np.zeros(n * width, np.float32)
                    if n:
                        psys.particles.foreach_get(name, a)
                    arrays[name] = a.reshape(n, width)
                self._particles[key] = arrays
            arrays = self._particles[key]
            if index >= len(arrays["size"]):
                arrays = None
        scalar = lambda v: (float(v),) * 4  # noqa: E731
        vector = lambda v: (float(v[0]), float(v[1]), float(v[2]), 1.0)  # noqa: E731
        if arrays is None:
            zero = vector((0.0, 0.0, 0.0))
            return dict(index=scalar(0.0), random=scalar(_hash_uint2_to_float(0, 0)), age=scalar(0.0),
                        lifetime=scalar(0.0), location=zero, size=scalar(0.0), velocity=zero,
                        angular_velocity=zero)
        return dict(index=scalar(index), random=scalar(_hash_uint2_to_float(index, 0)),
                    age=scalar(self.frame - arrays["birth_time"][index, 0]),
                    lifetime=scalar(arrays["lifetime"][index, 0]), location=vector(arrays["location"][index]),
                    size=scalar(arrays["size"][index, 0]), velocity=vector(arrays["velocity"][index]),
                    angular_velocity=vector(arrays["angular_velocity"][index]))

    @staticmethod
    def _dupli(instance, name, is_instance):
        if not is_instance:
            return (0.0, 0.0, 0.0, 1.0)
        if name == "uv":
            u, v = instance.uv
            return (u, v, 0.0, 1.0)
        x, y, z = instance.orco
        return (0.5 * x - 0.5, 0.5 * y - 0.5, 0.5 * z - 0.5, 1.0)

    def _top(self, parent):
        key = parent.as_pointer()
        if key not in self._trees:
            level = None
            # Only geometry nodes make instances with attributes: bpy's evaluated geometry also
            # lists an object's vertex / face / collection instancing (legacy instances, which
            # Cycles gives none), so an instancer without a Geometry Nodes modifier has none.
            if any(m.type == 'NODES' for m in parent.modifiers):
                try:
                    level = _Level(parent.evaluated_geometry(), parent.type)
                except (AttributeError, RuntimeError):
                    level = None
            self._trees[key] = level if level is not None and level.points is not None else None
        return self._trees[key]

    def _gn_levels(self, instance, parent):
        """[(_Level, instance index)] of a geometry-nodes instance, innermost first (the order
        Cycles looks attributes up in), followed down the instancer's geometry from the
        persistent id (outermost last; per geometry set, the components that make instances
        of their own take the first numbers and its instances then sit one level deeper);
        () for anything else."""
        level = self._top(parent)
        if level is None:
            return ()
        path = [p for p in instance.persistent_id if p != _UNUSED_ID][::-1]  # outermost first
        out = []
        pos = 0
        while level is not None and level.points is not None and pos < len(path):
            if level.components:
                if path[pos] != level.components:
                    break  # one of this geometry set's own components: the instance itself
                pos += 1
                if pos >= len(path):
                    break
            index = level.index_of(path[pos])
            if index is None:
                break
            out.append((level, index))
            pos += 1
            level = level.child(index)
        return tuple(reversed(out))

    def _value(self, kind, name, obj, parent, psys, gn):
        if kind in ("DUPLI", "PARTICLE"):
            return (0.0, 0.0, 0.0, 1.0)  # (per instance: see values())
        if kind == "INSTANCER":
            if psys is not None:
                v = property_rgba(psys.settings, name)
                if v is not None:
                    return v
            for level, index in gn:  # the innermost instance attribute of that name
                v = level.attribute(name, index)
                if v is not None:
                    return v
            if parent is not None:
                v = property_rgba(parent, name)
                if v is not None:
                    return v
        for holder in (obj, obj.data):
            v = property_rgba(holder, name)
            if v is not None:
                return v
        return (0.0, 0.0, 0.0, 0.0)
