"""The Attribute node's Object and Instancer attributes: per depsgraph instance, the RGBA value
of each scene-wide slot (shader.UvSets.object_attributes), looked up as Cycles 4.5 does
(BKE_object_dupli_find_rgba_attribute): for Instancer, on an instance, the particle settings,
the geometry-nodes instance attribute, then the instancing object; then the object and its
data. In each holder a custom property of that name before an RNA path ("color",
"location", "data.foo", '["prop"]'). A name found nowhere reads (0, 0, 0, 0). Also the
Texture Coordinate node's From Instancer coordinates (kind "DUPLI"): an instance's uv and orco
on its instancer, as Cycles' dupli_uv and dupli_generated (0.5 orco - 0.5), 0 elsewhere."""

import numpy as np

from .mesh import _attribute_rgba as attribute_rgba  # Cycles' conversions to RGBA

_UNUSED_ID = 2147483647  # persistent_id entries past the instance's nesting depth


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


class InstanceAttributes:
    """Resolves the slots for depsgraph instances of one export; values shared by every
    instance of the same holders (and geometry-nodes instance attributes) are read once."""

    def __init__(self, slots):
        self.slots = slots  # the live list of (kind, name): it grows as materials compile
        self._cache = {}
        self._gn = {}  # instancer pointer -> {name: float32 (N, 4) or None}

    def values(self, instance):
        """float32 (K, 4) for the first K slots (those numbered so far), or None with none."""
        if not self.slots:
            return None
        obj = instance.object
        is_instance = bool(instance.is_instance)
        parent = instance.parent if is_instance else None
        psys = instance.particle_system if is_instance else None
        gn_index = self._gn_index(instance) if is_instance and psys is None else None
        key = (obj.as_pointer(), parent.as_pointer() if parent is not None else 0,
               psys.as_pointer() if psys is not None else 0, gn_index, len(self.slots))
        out = self._cache.get(key)
        if out is None:
            out = np.array([self._value(kind, name, obj, parent, psys, gn_index)
                            for kind, name in self.slots], np.float32)
            self._cache[key] = out
        dupli = [(i, name) for i, (kind, name) in enumerate(self.slots) if kind == "DUPLI"]
        if dupli:  # per instance, not shared: each particle sits elsewhere on its emitter
            out = out.copy()
            for i, name in dupli:
                out[i] = self._dupli(instance, name, is_instance)
        return out

    @staticmethod
    def _dupli(instance, name, is_instance):
        if not is_instance:
            return (0.0, 0.0, 0.0, 1.0)
        if name == "uv":
            u, v = instance.uv
            return (u, v, 0.0, 1.0)
        x, y, z = instance.orco
        return (0.5 * x - 0.5, 0.5 * y - 0.5, 0.5 * z - 0.5, 1.0)

    @staticmethod
    def _gn_index(instance):
        """The instance's index among its instancer's geometry-nodes instances (a top-level
        one: persistent id (0, index)), else None."""
        ids = list(instance.persistent_id)
        if len(ids) >= 3 and ids[0] == 0 and ids[2] == _UNUSED_ID and ids[1] != _UNUSED_ID:
            return ids[1]
        return None

    def _gn_attribute(self, parent, name, index):
        per_name = self._gn.setdefault(parent.as_pointer(), {})
        if name not in per_name:
            values = None
            try:
                geometry = parent.evaluated_geometry()  # keeps the point cloud alive
                points = geometry.instances_pointcloud()
            except (AttributeError, RuntimeError):
                geometry = points = None
            if points is not None:
                attr = points.attributes.get(name)
                if attr is not None and not name.startswith("."):
                    values = attribute_rgba(attr)
            del geometry
            per_name[name] = values
        values = per_name[name]
        if values is None or not 0 <= index < len(values):
            return None
        return tuple(float(x) for x in values[index])

    def _value(self, kind, name, obj, parent, psys, gn_index):
        if kind == "DUPLI":
            return (0.0, 0.0, 0.0, 1.0)  # (per instance: see values())
        if kind == "INSTANCER":
            if psys is not None:
                v = property_rgba(psys.settings, name)
                if v is not None:
                    return v
            if parent is not None and gn_index is not None:
                v = self._gn_attribute(parent, name, gn_index)
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
