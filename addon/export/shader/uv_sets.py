"""The scene-wide numbering of UV maps and mesh attributes that programs read, and of the
Attribute node's Object / Instancer attributes (per-instance constants)."""

MAX_UV_SETS = 8
MAX_OBJECT_ATTRIBUTES = 8  # the core's per-instance slots (kMaxObjectAttributes)


class UvSets:
    """Global uv-set indices of UV map names across the scene; "" = each mesh's active render
    UV map."""

    def __init__(self):
        self.names = []  # index k -> name
        # Object attribute slot -> ("OBJECT" or "INSTANCER", name): what every instance's
        # values are resolved for (export.object_attributes).
        self.object_attributes = []
        # The rendered view layer's shader AOVs: name -> (slot, 'COLOR' or 'VALUE'), what AOV
        # Output nodes write (export_scene fills it; empty: the nodes are left out).
        self.aovs = {}

    def index(self, name):
        """k for `name`, or None when all MAX_UV_SETS are taken."""
        name = name or ""
        if name in self.names:
            return self.names.index(name)
        if len(self.names) >= MAX_UV_SETS:
            return None
        self.names.append(name)
        return len(self.names) - 1

    def object_attribute_slot(self, kind, name):
        """The per-instance slot of an Object ("OBJECT") or Instancer ("INSTANCER") attribute,
        of an instance's coordinates on its instancer ("DUPLI", "uv" or "generated") or of its
        particle's data ("PARTICLE", a Particle Info output), or None when all
        MAX_OBJECT_ATTRIBUTES are taken."""
        key = (kind, name)
        if key in self.object_attributes:
            return self.object_attributes.index(key)
        if len(self.object_attributes) >= MAX_OBJECT_ATTRIBUTES:
            return None
        self.object_attributes.append(key)
        return len(self.object_attributes) - 1
