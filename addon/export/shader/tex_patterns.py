"""Checker, Gradient, Brick and Voronoi Texture nodes → the core's pattern ops (evaluated as
Cycles does in core/scene/tex_patterns.cpp). Handlers of ShaderCompiler._VALUE_NODES: each takes
the compiler, the node, the output socket and the group context.

Every input socket is read as a value (constant or linked); an unlinked Vector reads the
Generated coordinates, as in Cycles. The ops are always emitted, never folded here: the core
evaluates a program that reads nothing from the shading point once."""


def _vector(c, node, ctx):
    """The Vector input, or the Generated coordinates when it is not linked."""
    v = _input(c, node, "Vector", ctx, "vector")
    if v is None:
        v = c.object_coords("generated")
    _note_texture_mapping(c, node)
    return v


def _note_texture_mapping(c, node):
    """The legacy per-node texture mapping (N panel) is not applied: warned when it is set."""
    m = getattr(node, "texture_mapping", None)
    if m is None:
        return
    identity = (tuple(m.translation) == (0.0, 0.0, 0.0) and tuple(m.rotation) == (0.0, 0.0, 0.0)
                and tuple(m.scale) == (1.0, 1.0, 1.0)
                and (m.mapping_x, m.mapping_y, m.mapping_z) == ('X', 'Y', 'Z')
                and not m.use_min and not m.use_max)
    if not identity:
        c.problem(f"'{node.name}': its Texture Mapping settings are not supported (ignored)")


def _input(c, node, name, ctx, kind):
    """An input by identifier: Blender's inputs[name] skips sockets the node's settings make
    unavailable (Voronoi's Smoothness, Exponent, W), which Cycles then does not read either."""
    for socket in node.inputs:
        if socket.identifier == name:
            return c.value(socket, ctx, kind)
    raise KeyError(f"'{node.name}' has no input {name}")


def _floats(c, node, ctx, names):
    return [c.reg(_input(c, node, name, ctx, "float")) for name in names]


def _colors(c, node, ctx, names):
    return [c.reg(_input(c, node, name, ctx, "color")) for name in names]


def checker(c, node, out, ctx):
    vec = _vector(c, node, ctx)
    colors = _colors(c, node, ctx, ("Color1", "Color2"))
    fac = out.identifier == "Fac"
    return c.emit("float" if fac else "color", "checker", c.reg(vec), *colors,
                  *_floats(c, node, ctx, ("Scale",)), "FAC" if fac else "COLOR")


def gradient(c, node, out, ctx):
    vec = _vector(c, node, ctx)
    kind = "float" if out.identifier == "Fac" else "color"
    return c.emit(kind, "gradient", c.reg(vec), node.gradient_type)


def brick(c, node, out, ctx):
    vec = _vector(c, node, ctx)
    colors = _colors(c, node, ctx, ("Color1", "Color2", "Mortar"))
    floats = _floats(c, node, ctx, ("Scale", "Mortar Size", "Mortar Smooth", "Bias",
                                    "Brick Width", "Row Height"))
    fac = out.identifier == "Fac"
    return c.emit("float" if fac else "color", "brick", c.reg(vec), *colors, *floats,
                  float(node.offset), int(node.offset_frequency), float(node.squash),
                  int(node.squash_frequency), "FAC" if fac else "COLOR")


_VORONOI_OUTPUTS = {"Distance": ("float", "DISTANCE"), "Color": ("color", "COLOR"),
                    "Position": ("vector", "POSITION"), "W": ("float", "W"),
                    "Radius": ("float", "RADIUS")}


def voronoi(c, node, out, ctx):
    dims = node.voronoi_dimensions
    kind, which = _VORONOI_OUTPUTS.get(out.identifier, ("float", "DISTANCE"))
    vec = None if dims == '1D' else c.reg(_vector(c, node, ctx))
    w = c.reg(_input(c, node, "W", ctx, "float")) if dims in ('1D', '4D') else None
    floats = _floats(c, node, ctx, ("Scale", "Detail", "Roughness", "Lacunarity", "Smoothness",
                                    "Exponent", "Randomness"))
    return c.emit(kind, "voronoi", vec, w, *floats, dims, node.feature, node.distance,
                  bool(node.normalize), which)


NODES = {'TEX_CHECKER': checker, 'TEX_GRADIENT': gradient, 'TEX_BRICK': brick,
         'TEX_VORONOI': voronoi}
