"""World → constant background radiance."""

from .material import BLACK, scaled, socket_rgb, surface_node


def world_color(world, warn):
    """Background radiance (colour * strength) as an RGB tuple."""
    if world is None:
        return BLACK
    if not world.use_nodes or world.node_tree is None:
        return tuple(world.color)
    node = surface_node(world.node_tree)
    if node is None:
        return BLACK  # nothing connected: Cycles renders a black world
    if node.type in {'BACKGROUND', 'EMISSION'}:  # Cycles treats both alike in a world
        color, strength = node.inputs["Color"], node.inputs["Strength"]
        if color.is_linked or strength.is_linked:
            warn(f"World '{world.name}': linked inputs of '{node.name}' are not supported yet; "
                 "using their constant values")
        return scaled(socket_rgb(color), strength.default_value)
    warn(f"World '{world.name}': node '{node.name}' ({node.bl_idname}) is not supported yet; "
         "using the world's colour")
    return tuple(world.color)
