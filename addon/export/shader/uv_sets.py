"""The scene-wide numbering of UV maps and mesh attributes that programs read."""

MAX_UV_SETS = 8


class UvSets:
    """Global uv-set indices of UV map names across the scene; "" = each mesh's active render
    UV map."""

    def __init__(self):
        self.names = []  # index k -> name

    def index(self, name):
        """k for `name`, or None when all MAX_UV_SETS are taken."""
        name = name or ""
        if name in self.names:
            return self.names.index(name)
        if len(self.names) >= MAX_UV_SETS:
            return None
        self.names.append(name)
        return len(self.names) - 1
