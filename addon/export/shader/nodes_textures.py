"""Texture nodes: Image, Noise, Wave, Magic, White Noise, Gabor, Sky, Environment and Point
Density (a ShaderCompiler mixin; Checker, Gradient, Brick and Voronoi are tex_patterns'.)"""

from .images import MISSING_TEXTURE
from .values import ONE, ZERO, Val, const_color, const_vector

# Point Density resolutions above this are refused (warned): bpy returns the voxels as a tuple of
# Python floats, about 1 GB at 200^3.
MAX_POINT_DENSITY_RESOLUTION = 200


class TextureNodes:
    """Translators of the texture nodes (ShaderCompiler mixin)."""

    def image_texture(self, node, out, ctx):
        what = f"'{node.name}'"
        image = node.image
        loaded = None
        if image is not None:  # (a sequence's or movie's frame: the node's at the scene frame)
            loaded = self.images.load(image, self.problems, getattr(node, "image_user", None),
                                      self.scene_frame())
        if image is None:
            self.problem(f"{what} has no image (magenta)")
        if loaded is None:
            if out.identifier == "Alpha":
                return ONE
            return const_color(MISSING_TEXTURE)
        if out.identifier == "Alpha" and not loaded.has_alpha:
            return ONE
        vec = self.value(node.inputs["Vector"], ctx, "vector")
        if vec is None:
            vec = self.uv_value("", what)
        interp = {"Closest": "CLOSEST", "Cubic": "CUBIC", "Smart": "CUBIC"}.get(node.interpolation, "LINEAR")
        ext = node.extension if node.extension in ('REPEAT', 'EXTEND', 'CLIP', 'MIRROR') else 'REPEAT'
        projection = node.projection
        if projection in ('SPHERE', 'TUBE'):  # Cycles maps the vector first, then picks the tile
            vec = self.emit("vector", "image_proj", self.reg(vec), projection)
        elif projection != 'FLAT' and projection != 'BOX':
            self.problem(f"{what}: {projection.lower()} projection is not supported (flat)")
            projection = 'FLAT'
        alpha_out = node.outputs.get("Alpha")
        if out.identifier == "Alpha":
            kind, variant, unassociate = "float", "alpha", False
        else:  # As Cycles: with the Alpha output in use, Color is divided by the filtered alpha.
            kind, variant = "color", "color"
            unassociate = (alpha_out is not None and alpha_out.is_linked and loaded.has_alpha
                           and loaded.unassociate)
        owner = None
        if projection != 'BOX' and getattr(loaded, "tiles", None) is not None:
            uv_map = self.culling_uv_map(node, ctx)
            material = getattr(self, "material_key", None)
            owner = None if uv_map is None or material is None else (material, uv_map)
        index = self.images.index(image, loaded, variant, owner)
        tail = (True,) if unassociate else ()
        if projection == 'BOX':  # (a tiled image: its first tile only, as Cycles)
            normal = self.emit("vector", "object_normal")
            return self.emit(kind, "image_box", self.reg(vec), self.reg(normal), index, interp, ext,
                             float(node.projection_blend), *tail)
        return self.emit(kind, "image", self.reg(vec), index, interp, ext, *tail)

    def culling_uv_map(self, node, ctx):
        """The UV map whose corners pick the tiles that Cycles' final renders load for Image
        Texture `node` (ImageTextureNode::cull_tiles): the default one ("") when its Vector is
        unlinked or the Texture Coordinate's UV, a UV Map node's map; None (every tile) when
        anything else feeds it."""
        src = self.source(node.inputs["Vector"], ctx)
        for _ in range(100):  # (through identity Mapping nodes, which Cycles bypasses)
            if src is None or src[0] == "default":
                return ""
            _, feeder, out, fctx = src
            if feeder.bl_idname == "ShaderNodeUVMap":
                return feeder.uv_map or ""
            if feeder.bl_idname == "ShaderNodeTexCoord" and out.identifier == "UV":
                return ""
            if feeder.bl_idname != "ShaderNodeMapping" or not self._identity_mapping(feeder, fctx):
                return None
            src = self.source(feeder.inputs["Vector"], fctx)
        return None

    def _identity_mapping(self, node, ctx):
        """True for a Mapping node that Cycles' ConstantFolder::fold_mapping bypasses: its
        Location zero (or type Vector), Rotation zero and Scale one, none of them linked."""
        if node.vector_type not in ('POINT', 'TEXTURE', 'VECTOR'):
            return False
        want = {"Rotation": 0.0, "Scale": 1.0}
        if node.vector_type != 'VECTOR':
            want["Location"] = 0.0
        for name, value in want.items():
            socket = node.inputs.get(name)
            if socket is None:
                continue
            src = self.source(socket, ctx)
            if src is not None and src[0] != "default":
                return False
            socket = socket if src is None else src[1]
            if any(float(c) != value for c in socket.default_value):
                return False
        return True

    def scene_frame(self):
        """The frame that animated images show (None: the file their path names)."""
        frame = getattr(self, "frame", None)
        if frame is None and self.depsgraph is not None:
            frame = self.depsgraph.scene.frame_current
        return frame

    # -------------------------------------------------- procedural textures (issue 21)

    def texture_vector(self, node, ctx):
        """A texture node's Vector: the linked value, or (unlinked) Generated coordinates, as
        Cycles links them in (its ops follow the Bump node's offsets)."""
        tm = node.texture_mapping  # the sidebar's Texture Mapping panel, rarely changed
        if (any(tm.translation) or any(tm.rotation) or tuple(tm.scale) != (1.0, 1.0, 1.0)
                or tm.use_min or tm.use_max or tm.mapping != 'FLAT'
                or (tm.mapping_x, tm.mapping_y, tm.mapping_z) != ('X', 'Y', 'Z')):
            self.problem(f"'{node.name}': its Texture Mapping settings are not supported "
                         "(ignored; a Mapping node works)")
        socket = next(s for s in node.inputs if s.identifier == "Vector")
        vec = self.value(socket, ctx, "vector")
        return self.object_coords("generated") if vec is None else vec

    def _texture_floats(self, node, names, ctx):
        """Registers of float inputs, found by identifier: inputs[name] skips the sockets
        that the node's mode makes unavailable (W of 3D noise), which still read as their
        values (the core ignores what the mode does not use)."""
        by_id = {s.identifier: s for s in node.inputs}
        return [self.reg(self.value(by_id[name], ctx, "float")) for name in names]

    def noise_texture(self, node, out, ctx):
        """Cycles' Noise Texture (always emitted: the core evaluates a non-varying program once)."""
        dims = int(node.noise_dimensions[0])
        vec = None if dims == 1 else self.reg(self.texture_vector(node, ctx))  # 1D reads only W
        floats = self._texture_floats(node, ("W", "Scale", "Detail", "Roughness", "Lacunarity",
                                             "Offset", "Gain", "Distortion"), ctx)
        color = out.identifier == "Color"
        return self.emit("color" if color else "float", "tex_noise", vec, *floats, dims,
                         node.noise_type, bool(node.normalize), color)

    def wave_texture(self, node, out, ctx):
        vec = self.reg(self.texture_vector(node, ctx))
        floats = self._texture_floats(node, ("Scale", "Distortion", "Detail", "Detail Scale",
                                             "Detail Roughness", "Phase Offset"), ctx)
        direction = node.bands_direction if node.wave_type == 'BANDS' else node.rings_direction
        kind = "color" if out.identifier == "Color" else "float"  # Color is (Fac, Fac, Fac)
        return self.emit(kind, "tex_wave", vec, *floats, node.wave_type, direction,
                         node.wave_profile)

    def magic_texture(self, node, out, ctx):
        vec = self.reg(self.texture_vector(node, ctx))
        floats = self._texture_floats(node, ("Scale", "Distortion"), ctx)
        color = out.identifier == "Color"
        return self.emit("color" if color else "float", "tex_magic", vec, *floats,
                         int(node.turbulence_depth), color)

    def white_noise_texture(self, node, out, ctx):
        dims = int(node.noise_dimensions[0])
        vec = None
        if dims != 1:
            v = self.value(next(s for s in node.inputs if s.identifier == "Vector"), ctx,
                           "vector")
            # Cycles gives this node no implicit coordinates: unlinked, its Vector is (0, 0, 0).
            vec = self.reg(v if v is not None else const_vector((0, 0, 0)))
        (w,) = self._texture_floats(node, ("W",), ctx)
        color = out.identifier == "Color"
        return self.emit("color" if color else "float", "tex_white_noise", vec, w, dims, color)

    def gabor_texture(self, node, out, ctx):
        """Cycles' Gabor Texture, 2D and 3D, every output."""
        vec = self.reg(self.texture_vector(node, ctx))
        floats = self._texture_floats(node, ("Scale", "Frequency", "Anisotropy", "Orientation 2D"),
                                      ctx)
        o3 = self.reg(self._vector_or_zero(node, "Orientation 3D", ctx))
        which = {"Phase": "PHASE", "Intensity": "INTENSITY"}.get(out.identifier, "VALUE")
        return self.emit("float", "tex_gabor", vec, *floats, o3, node.gabor_type, which)


    def ies_texture(self, node, out, ctx):
        """Cycles' IES Texture (svm_node_ies): the profile along its normalised Vector, times
        Strength. Unlinked, Cycles' LINK_TEXTURE_INCOMING: Geometry's Incoming turned into
        object space as a normal (for a light: the direction from it to the lit point, in its
        frame). Without a usable profile Cycles' kernel reads 100 (light.IES_FALLBACK)."""
        from ..light import IES_FALLBACK, ies_profile  # (light export shares the reader)
        strength = self.input(node, "Strength", ctx, "float")
        profile = ies_profile(node, self.problem)
        if profile is None:
            return self.math("MULTIPLY", strength, Val("float", (IES_FALLBACK,) * 3 + (1.0,)))
        vec = self.value(node.inputs["Vector"], ctx, "vector")
        if vec is None:
            incoming = self.emit("vector", "geometry", "INCOMING")
            vec = self.emit("vector", "vector_transform", self.reg(incoming), "NORMAL", "WORLD", "OBJECT")
        return self.emit("float", "tex_ies", self.reg(vec), self.reg(strength), profile)

    def environment_texture(self, node, out, ctx):
        """Cycles' Environment Texture (svm_node_tex_environment): its image looked up along the
        normalised Vector (equirectangular or mirror ball), Repeat extension. Unlinked, Cycles'
        LINK_POSITION: the position (a world's: the ray's direction)."""
        what = f"'{node.name}'"
        image = node.image
        loaded = None
        if image is not None:  # (a sequence's frame: the node's at the scene frame)
            loaded = self.images.load(image, self.problems, getattr(node, "image_user", None),
                                      self.scene_frame())
        if image is None:
            self.problem(f"{what} has no image (magenta)")
        if loaded is None:
            return ONE if out.identifier == "Alpha" else const_color(MISSING_TEXTURE)
        if out.identifier == "Alpha" and not loaded.has_alpha:
            return ONE
        socket = next(s for s in node.inputs if s.identifier == "Vector")
        vec = self.value(socket, ctx, "vector")
        if vec is None:
            vec = self.position()
        tm = node.texture_mapping
        if (any(tm.translation) or any(tm.rotation) or tuple(tm.scale) != (1.0, 1.0, 1.0)
                or tm.use_min or tm.use_max
                or (tm.mapping_x, tm.mapping_y, tm.mapping_z) != ('X', 'Y', 'Z')):
            self.problem(f"{what}: its Texture Mapping settings are not supported "
                         "(ignored; a Mapping node works)")
        projection = 'MIRROR_BALL' if node.projection == 'MIRROR_BALL' else 'EQUIRECTANGULAR'
        if node.projection not in ('EQUIRECTANGULAR', 'MIRROR_BALL'):
            self.problem(f"{what}: {node.projection.lower()} projection is not supported (equirectangular)")
        uv = self.emit("vector", "env_uv", self.reg(vec), projection)
        interp = {"Closest": "CLOSEST", "Cubic": "CUBIC", "Smart": "CUBIC"}.get(node.interpolation, "LINEAR")
        if out.identifier == "Alpha":
            index = self.images.index(image, loaded, "alpha")
            return self.emit("float", "image", self.reg(uv), index, interp, 'REPEAT')
        index = self.images.index(image, loaded, "color")
        alpha_out = node.outputs.get("Alpha")
        if alpha_out is not None and alpha_out.is_linked and loaded.has_alpha and loaded.unassociate:
            return self.emit("color", "image", self.reg(uv), index, interp, 'REPEAT', True)
        return self.emit("color", "image", self.reg(uv), index, interp, 'REPEAT')

    def sky_texture(self, node, out, ctx):
        """Cycles' Sky Texture in a material (svm_node_tex_sky): the world's sky model read
        along the Vector as it is (unlinked, or Nishita's unavailable socket: Generated
        coordinates, Cycles' default)."""
        from ...core import get_core
        from ..world import sky_params
        what = f"'{node.name}'"
        socket = node.inputs.get("Vector")
        vec = None
        if socket is not None and socket.enabled:
            vec = self.texture_vector(node, ctx)
        else:
            vec = self.object_coords("generated")
            if getattr(self, "background", False):
                # A world's sky: the node's Python-only texture mapping as the fast path applies
                # it (rotations; other settings warned about and ignored).
                import numpy as np
                from ..world import _texture_mapping_rotation
                rot = _texture_mapping_rotation(getattr(node, "texture_mapping", None), what, self.problem)
                if not np.array_equal(rot, np.eye(3, dtype=np.float32)):
                    m = np.hstack([rot.astype(np.float32), np.zeros((3, 1), np.float32)])
                    vec = self.emit("vector", "mapping", self.reg(vec), m)
        key = ("sky", node.as_pointer())
        sky = self.cache.get(key)
        if sky is None:
            try:
                if node.sky_type == 'NISHITA':
                    sky = get_core().sky_texture("NISHITA", **sky_params(node))
                elif node.sky_type in ('PREETHAM', 'HOSEK_WILKIE'):
                    sky = get_core().sky_texture(
                        node.sky_type, sun_direction=tuple(float(c) for c in node.sun_direction),
                        turbidity=float(node.turbidity), ground_albedo=float(node.ground_albedo))
            except (ValueError, AttributeError) as e:
                self.problem(f"{what}: {e} (black)")
            if sky is None:
                self.problem(f"{what}: sky type {node.sky_type} is not supported (black)")
                return const_color((0.0, 0.0, 0.0, 1.0))
            self.cache[key] = sky
        return self.emit("color", "tex_sky", self.reg(vec), sky)

    def point_density_texture(self, node, out, ctx):
        """Point Density (Cycles' svm_node_tex_voxel): Blender voxelises the particles or vertices
        (node.calc_point_density over calc_point_density_minmax, in the source object's space);
        the voxels go to the core as a scene grid read at the Vector (Position by default) in
        the node's space: World through the source object's transform and bounds, Object in the
        shading object's generated coordinates. Volumes only, as Cycles
        (docs/design/volumes.md "Volume Coefficients and Point Density")."""
        density = out.identifier == "Density"
        black = ZERO if density else const_color((0.0, 0.0, 0.0, 1.0))
        if not self.in_volume:
            # Cycles 4.5 runs svm_node_tex_voxel in volume shaders only: 0 elsewhere (measured).
            self.problem(f"'{node.name}': the Point Density texture works in volumes only "
                         "(Density 0, Color black elsewhere, as Cycles)")
            return black
        grid = self._point_density_grid(node, density)
        if grid is None:
            return black
        vec = self.value(node.inputs["Vector"], ctx, "vector")
        if vec is None:
            vec = self.position()
        interp = {"Closest": "CLOSEST", "Cubic": "CUBIC"}.get(node.interpolation, "LINEAR")
        # Object space: the shading object's generated coordinates (Cycles' volume_normalized_position).
        space = "WORLD" if node.space == 'WORLD' else "TEXTURE"
        return self.emit("float" if density else "color", "tex_voxel", self.reg(vec), grid,
                         "FAC" if density else "COLOR", interp, space)

    def _point_density_grid(self, node, density):
        """The scene grid id of the node's Density (1 channel) or Color (3), made once per node
        and export; None (with a problem where it is not Cycles' 0) where there is nothing."""
        key = ("point_density", node.as_pointer(), density)
        if key not in self.scene_grid_cache:
            voxels = self._point_density_voxels(node)
            self.scene_grid_cache[key] = None if voxels is None else \
                self._add_point_density_grid(node, voxels, density)
        return self.scene_grid_cache[key]

    def _point_density_voxels(self, node):
        """(RGBA voxels [z, y, x, 4], index -> texture-space matrix) of a node, read once per
        export (Blender frees its cache after each calc_point_density), or None."""
        import numpy as np
        key = ("point_density voxels", node.as_pointer())
        if key in self.scene_grid_cache:
            return self.scene_grid_cache[key]
        self.scene_grid_cache[key] = None
        what = f"Point Density '{node.name}'"
        ob, dg, res = node.object, self.depsgraph, int(node.resolution)
        if ob is None or (node.point_source == 'PARTICLE_SYSTEM' and node.particle_system is None):
            return None  # Cycles: nothing to read, Density 0 and Color black
        if self.scene_grids is None or dg is None:
            self.problem(f"{what}: not available here (no scene export; Density 0, Color black)")
            return None
        if res > MAX_POINT_DENSITY_RESOLUTION:
            # bpy hands the voxels over as a tuple of Python floats (32 bytes each): 1 GB at 200^3.
            self.problem(f"{what}: resolution {res} is above {MAX_POINT_DENSITY_RESOLUTION} "
                         "(Density 0, Color black)")
            return None
        try:
            node.cache_point_density(depsgraph=dg)
            lo, hi = (np.asarray(v, np.float64) for v in node.calc_point_density_minmax(depsgraph=dg))
            pixels = np.asarray(node.calc_point_density(depsgraph=dg), np.float32)
        except (RuntimeError, TypeError, ValueError) as e:
            self.problem(f"{what}: Blender could not voxelise its points ({e}); Density 0, Color black")
            return None
        if res < 1 or pixels.size != res ** 3 * 4 or not np.all(hi >= lo):
            return None  # no points (Blender's bounds stay inverted): Cycles reads 0 too
        # Index -> texture space [0, 1]^3: voxel i's centre at (i + 0.5) / res (Cycles' 3D lookup).
        m = np.diag([1.0 / res, 1.0 / res, 1.0 / res, 1.0])
        m[:3, 3] = 0.5 / res
        if node.space == 'WORLD':
            # Cycles: texture space = (p_object - min) / (max - min) in the source object's space.
            size = hi - lo
            if not np.all(size > 0.0):
                self.problem(f"{what}: its points' bounds are flat (radius 0?): Density 0, Color black")
                return None
            box = np.eye(4)
            box[:3, :3] = np.diag(size)
            box[:3, 3] = lo
            ev = ob.evaluated_get(dg) if hasattr(ob, "evaluated_get") else ob
            m = np.asarray(ev.matrix_world, np.float64) @ box @ m
        voxels = (pixels.reshape(res, res, res, 4), m)  # [z, y, x, rgba]: Blender's x fastest
        self.scene_grid_cache[key] = voxels
        return voxels

    def _add_point_density_grid(self, node, voxels, density):
        import numpy as np
        from ...core import get_core
        pixels, m = voxels
        values = np.ascontiguousarray(pixels[..., 3] if density else pixels[..., :3])
        try:
            grid = get_core().VolumeGrid.from_dense(values, m)
        except (RuntimeError, ValueError) as e:
            self.problem(f"Point Density '{node.name}': {e} (Density 0, Color black)")
            return None
        self.scene_grids.append(grid)
        return len(self.scene_grids) - 1



# Handlers of ShaderCompiler._VALUE_NODES (Image Texture is eval_value_node's).
VALUE_NODES = {
    'TEX_NOISE': TextureNodes.noise_texture, 'TEX_WAVE': TextureNodes.wave_texture,
    'TEX_MAGIC': TextureNodes.magic_texture, 'TEX_WHITE_NOISE': TextureNodes.white_noise_texture,
    'TEX_GABOR': TextureNodes.gabor_texture, 'TEX_IES': TextureNodes.ies_texture,
    'TEX_SKY': TextureNodes.sky_texture, 'TEX_ENVIRONMENT': TextureNodes.environment_texture,
    'TEX_POINTDENSITY': TextureNodes.point_density_texture,
}
