"""The one module that writes the core scene: SceneData (and its parts) from addon/export/ →
pc.Scene calls (add_mesh, add_instance, add_shader, add_<kind>_light, set_world_*, ...).

addon/export/ turns the depsgraph into plain arrays, tuples and dataclasses and never touches
the core; final renders (session.py), the kept scene of the last render (render_cache.py) and
the viewport's live edits (viewport.py) all write through the functions here.
tests/blender/test_scene_writer.py fails if any other add-on module calls a core scene writer."""

import weakref

import numpy as np

from .export.light_linking import ALL_SETS
from .export.material import cryptomatte_name
from .export.world import WorldSky


def to_core(pc, data, warn=None, material_ids=None, image_ids=None):
    """A pc.Scene (not committed) holding SceneData `data`. warn(msg) hears about what this
    build of the core cannot do. material_ids, image_ids: lists that receive the core id of
    each of data.materials and data.images (for live edits and reuse)."""
    warn = warn if warn is not None else (lambda msg: None)
    groups = getattr(data, "light_groups", None) or []
    scene = pc.Scene()
    for k, grid in enumerate(getattr(data, "volume_grids", [])):
        if scene.add_volume_grid(grid) != k:  # (programs name grids by their index here)
            raise RuntimeError("volume grid ids out of order")
    ids = add_materials(scene, data.materials, data.images, warn, image_ids)
    if material_ids is not None:
        material_ids.extend(ids)
    for mesh, slots in zip(data.meshes, data.material_slots):
        uvs = {"uvs": mesh.uvs} if mesh.uvs else {}
        if mesh.attributes:
            uvs["attributes"] = mesh.attributes
        if mesh.texspace is not None:
            uvs["texspace"] = mesh.texspace
        if getattr(mesh, "tangents", None):
            uvs["tangents"] = mesh.tangents
        positions, normals, normal_indices = mesh.positions, mesh.normals, mesh.normal_indices
        moved = {}
        deform = getattr(mesh, "motion_positions", None)
        displaced = displace(scene, mesh, [ids[i] for i in slots], uvs, deform, warn) \
            if any(getattr(data.materials[i], "displacement", None) for i in slots) else None
        if displaced is not None:
            positions = displaced["positions"]
            normals = displaced.get("normals", normals)
            normal_indices = displaced.get("normal_indices", normal_indices)
            deform = displaced.get("motion_positions", deform)
            moved = {"undisplaced": mesh.positions}  # (Generated coordinates, the bump of 'BOTH')
        mesh_id = scene.add_mesh(positions, mesh.triangles,
                                 normals=normals, normal_indices=normal_indices,
                                 material_indices=mesh.material_indices,
                                 material_slots=[ids[i] for i in slots], **uvs, **moved)
        infos = mesh.infos if len(mesh.infos) == len(mesh.matrices) else [None] * len(mesh.matrices)
        names = [name for name, _ in mesh.owners] if len(mesh.owners) == len(mesh.matrices) else None
        if deform is not None:
            scene.set_mesh_motion(mesh_id, deform)
        velocity = getattr(mesh, "velocity", None)
        if velocity is not None:  # a volume object's velocity blur
            ids, scale, offset, interpolation = velocity
            yz = {"grid_y": ids[1], "grid_z": ids[2]} if len(ids) == 3 else {}
            scene.set_mesh_velocity(mesh_id, ids[0], scale, offset, interpolation, **yz)
        pass_positions = getattr(mesh, "pass_positions", None)
        if pass_positions is not None and not scene.set_mesh_pass_motion(mesh_id, pass_positions):
            warn(f"Mesh '{mesh.name}': its positions at the frames around this one do not fit "
                 "the mesh; the Vector pass leaves out its deformation")
        motions = getattr(mesh, "motions", None) or []
        pass_motions = getattr(mesh, "pass_motions", None) or []
        links = getattr(data, "light_links", None)
        attributes = getattr(mesh, "object_attributes", None) or []
        for k, (matrix, info) in enumerate(zip(mesh.matrices, infos)):
            # Motion blur steps only where the object moves (and so never for older cores).
            extra = {"motion": motions[k]} if k < len(motions) and motions[k] is not None else {}
            if k < len(pass_motions) and pass_motions[k] is not None:  # the Vector pass
                extra["pass_motion"] = pass_motions[k]
            # Object / Instancer attribute values only where materials read them (so never
            # for older cores).
            if k < len(attributes) and attributes[k] is not None and len(attributes[k]):
                extra["attributes"] = attributes[k]
            link = links.get(names[k]) if links and names else None
            if link is not None:  # light linking (so never for older cores)
                extra.update(light_set=link[0], light_mask=link[1], shadow_set=link[2], shadow_mask=link[3])
            if info is None:
                scene.add_instance(mesh_id, matrix, **extra)
                continue
            color, pass_index, random_id, terminator = info[:4]
            if random_id is None:
                random_id = pc.object_random_id(names[k]) if names else 0
            scene.add_instance(mesh_id, matrix, color=color, pass_index=pass_index, random_id=random_id,
                               shadow_terminator=terminator, **_crypto(info), **_catcher_holdout(info),
                               **_ao_distance(info), **_light_group(info, groups), **extra)
    curves = getattr(data, "curves", [])
    if curves:
        mats = iter(data.curve_materials)
        add_curves(scene, curves, lambda _material: ids[next(mats)], warn,
                   pc.object_random_id, getattr(data, "light_links", None), groups)
    points = getattr(data, "points", [])
    if points:
        mats = iter(data.point_materials)
        add_points(scene, points, lambda _material: ids[next(mats)], warn, pc.object_random_id,
                   getattr(data, "light_links", None), groups)
    add_lights(scene, data.lights, groups)
    set_world(scene, data, warn)
    set_camera(pc, scene, data.camera)
    return scene


def displace(scene, mesh, slot_ids, uvs, deform, warn):
    """The core's true displacement of a MeshData whose materials displace (Cycles: before the
    BVH, shaded as its first instance places it; deformation steps move by the same offsets):
    displace_mesh's dict, or None (nothing displaced, or a core without it)."""
    if not hasattr(scene, "displace_mesh") or not mesh.matrices:
        return None
    extra = {k: v for k, v in uvs.items() if k in ("uvs", "attributes", "tangents", "texspace")}
    flat = getattr(mesh, "flat", None)
    if flat is not None:
        extra["flat"] = flat
    if deform is not None:
        extra["motion_positions"] = deform
    out = scene.displace_mesh(mesh.positions, mesh.triangles, material_indices=mesh.material_indices,
                              material_slots=slot_ids, matrix=mesh.matrices[0], normals=mesh.normals,
                              normal_indices=mesh.normal_indices, **extra)
    if out is not None and out["clamped"]:
        warn(f"Mesh '{mesh.name}': {out['clamped']} non-finite or huge displacement offsets "
             "were dropped or shortened")
    return out


def add_materials(scene, materials, images, warn, image_ids=None):
    """Adds MaterialData `materials` (and the ImageData `images` their programs use) to a core
    scene; returns the core material ids. image_ids: a list that receives the core id of each
    image (put_material needs them to replace a material later). Core builds without shader
    programs get the (base colour, emission) summary."""
    ids = []
    for image in images:  # (a tile set's tiles come before it)
        if getattr(image, "tiles", ()):
            ids.append(scene.add_image_tiles([(n, ids[k]) for n, k in image.tiles]))
        else:
            ids.append(scene.add_image(image.pixels, srgb=image.srgb) if image.srgb
                       else scene.add_image(image.pixels))
    if image_ids is not None:
        image_ids.extend(ids)
    return [put_material(scene, m, ids) for m in materials]


def remap_images(ops, image_ids):
    """A program's image ops with their image operands replaced by the core ids image_ids."""
    at = {"image": 3, "image_box": 4}  # where the image operand sits (after the registers)
    return [op[:at[op[0]]] + (image_ids[op[at[op[0]]]],) + op[at[op[0]] + 1:] if op[0] in at else op
            for op in ops]


def put_material(scene, m, image_ids, core_id=None):
    """Adds MaterialData `m` to a core scene (core_id None) or replaces material `core_id` with
    it; image_ids: the core ids of the images its program reads. Returns the material's id.
    Core builds without shader programs get the (base colour, emission) summary."""
    if m.program is None:
        if core_id is None:
            core_id = scene.add_material(m.name, base_color=m.base_color, emission=m.emission)
        else:
            scene.set_material(core_id, m.name, base_color=m.base_color, emission=m.emission)
        if m.pass_index:
            scene.set_material_pass_index(core_id, m.pass_index)
        scene.set_material_cryptomatte(core_id, cryptomatte_name(m))
        return core_id
    def remap(ops):
        return remap_images(ops, image_ids)
    program = remap(m.program)
    kw = {} if m.volume is None else {"volume": m.volume}  # older cores lack it
    if getattr(m, "displacement", None):
        kw["displacement"] = remap(m.displacement)
        kw["displacement_method"] = m.displacement_method
    if core_id is None:
        core_id = scene.add_shader(m.name, program, volume_absorption=m.volume_absorption,
                                   use_schlick=m.use_schlick, **kw)
    else:
        scene.set_shader(core_id, m.name, program, volume_absorption=m.volume_absorption,
                         use_schlick=m.use_schlick, **kw)
    if m.pass_index:
        scene.set_material_pass_index(core_id, m.pass_index)
    scene.set_material_cryptomatte(core_id, cryptomatte_name(m))
    return core_id


def _crypto(info):
    """add_instance / add_curves / add_points keywords of an object's Cryptomatte names (the
    fifth entry of mesh.object_info's tuple; none in older tuples)."""
    return {"cryptomatte": info[4]} if len(info) > 4 and info[4] is not None else {}


def _ao_distance(info):
    """add_instance / add_curves / add_points keyword of an object's Fast GI AO Distance
    (mesh.object_info's ninth entry), only where set."""
    return {"ao_distance": info[8]} if len(info) > 8 and info[8] > 0.0 else {}


def _catcher_holdout(info):
    """add_instance / add_curves / add_points keywords of an object's Shadow Catcher and Holdout
    (mesh.object_info's sixth and seventh entries), only where set."""
    out = {"shadow_catcher": info[5], "holdout": info[6]} if len(info) > 6 and (info[5] or info[6]) else {}
    if len(info) > 9 and info[9]:  # Indirect Only (mesh.object_info's tenth entry)
        out["camera_invisible"] = True
    return out


def group_index(groups, name):
    """The core's light group of an emitter whose Light Group is `name`: its index in the view
    layer's light groups `groups`, or -1 (none: empty, or a name the view layer does not list,
    as Cycles' lightgroup map leaves such objects out)."""
    try:
        return groups.index(name) if name else -1
    except ValueError:
        return -1


def _light_group(info, groups):
    """add_instance / add_curves / add_points keywords of an object's light group
    (mesh.object_info's eighth entry), only where it is in one."""
    g = group_index(groups, info[7]) if len(info) > 7 and groups else -1
    return {"light_group": g} if g >= 0 else {}


def _motion_args(entry, k):
    """add_curves / add_points keywords for motion blur of instance k of a CurvesData or
    PointsData: its transform steps and the geometry's deformation steps (export.motion), and
    its matrices and points at the frames around for the Vector pass."""
    out = {}
    motions = getattr(entry, "motions", None) or []
    if k < len(motions) and motions[k] is not None:
        out["motion"] = motions[k]
    pass_motions = getattr(entry, "pass_motions", None) or []
    if k < len(pass_motions) and pass_motions[k] is not None:
        out["pass_motion"] = pass_motions[k]
    pass_points = getattr(entry, "pass_points", None)
    if pass_points is not None:
        out["pass_points"] = pass_points
    points = getattr(entry, "motion_points", None)
    if points is not None:
        out["motion_points"] = points
        radii = getattr(entry, "motion_radii", None)
        if radii is not None:
            out["motion_radii"] = radii
    return out


def _link_sets(links, owners, k):
    """add_curves / add_points' light linking arguments of instance k: its object's light and
    shadow sets as a receiver and a blocker, and as an emitter its light and shadow masks (an
    emissive material with linking of its own), or none."""
    link = links.get(owners[k]) if links and k < len(owners) else None
    if link is None:
        return {}
    out = {"light_set": link[0], "shadow_set": link[2]} if link[0] or link[2] else {}
    if link[1] != ALL_SETS or link[3] != ALL_SETS:
        out.update(light_mask=link[1], shadow_mask=link[3])
    return out


def add_curves(scene, curves, material_ids, warn, random_id_of=None, links=None, groups=()):
    """Adds CurvesData `curves` to a core scene; material_ids(material) -> core material id;
    random_id_of(name): the random id of a non-instanced object (Object Info's Random);
    links: export.light_linking.light_links' dict (object name -> sets and masks) or None;
    groups: the view layer's light group names (SceneData.light_groups)."""
    groups = list(groups)
    for c in curves:
        mat = material_ids(c.material)
        infos = c.infos if len(c.infos) == len(c.matrices) else [None] * len(c.matrices)
        attributes = getattr(c, "object_attributes", None) or []
        owners = getattr(c, "owners", None) or []
        for k, (m, info) in enumerate(zip(c.matrices, infos)):
            # Object / Instancer attribute values only where materials read them.
            extra = {"uvs": c.uvs} if getattr(c, "uvs", None) else {}
            extra.update(_link_sets(links, owners, k))  # (so never for older cores)
            if getattr(c, "colours", None):
                extra["strand_attributes"] = c.colours
            if getattr(c, "point_attributes", None):
                extra["point_attributes"] = c.point_attributes
            if getattr(c, "point_uvs", None):
                extra["point_uvs"] = c.point_uvs
            if getattr(c, "normals", None) is not None:
                extra["normals"] = c.normals
            if k < len(attributes) and attributes[k] is not None and len(attributes[k]):
                extra["attributes"] = attributes[k]
            if getattr(c, "shape", 'thick') == 'ribbon':  # (so never for older cores)
                extra["shape"] = 'ribbon'
                extra["subdivisions"] = int(c.subdivisions)
            extra.update(_motion_args(c, k))
            try:
                if info is None:
                    scene.add_curves(c.points, c.offsets, c.radii, mat, matrix=m, curve_type=c.curve_type,
                                     **extra)
                    continue
                color, pass_index, random_id, _ = info[:4]
                if random_id is None:
                    random_id = random_id_of(c.name) if random_id_of else 0
                scene.add_curves(c.points, c.offsets, c.radii, mat, matrix=m, curve_type=c.curve_type,
                                 color=color, pass_index=pass_index, random_id=random_id, **_crypto(info),
                                 **_catcher_holdout(info), **_ao_distance(info), **_light_group(info, groups), **extra)
            except ValueError as e:  # inconsistent arrays: the object is left out, Blender goes on
                warn(f"Curves '{c.name}' not rendered: {e}")
                break


def add_points(scene, points, material_ids, warn, random_id_of=None, links=None, groups=()):
    """Adds PointsData `points` to a core scene, one point set per instance; material_ids,
    random_id_of, links and groups as add_curves'."""
    groups = list(groups)
    for p in points:
        mat = material_ids(p.material)
        infos = p.infos if len(p.infos) == len(p.matrices) else [None] * len(p.matrices)
        attributes = getattr(p, "object_attributes", None) or []
        owners = getattr(p, "owners", None) or []
        for k, (m, info) in enumerate(zip(p.matrices, infos)):
            extra = {"point_attributes": p.attributes} if p.attributes else {}
            extra.update(_link_sets(links, owners, k))
            extra.update(_motion_args(p, k))
            if k < len(attributes) and attributes[k] is not None and len(attributes[k]):
                extra["attributes"] = attributes[k]
            if info is not None:
                color, pass_index, random_id, _ = info[:4]
                if random_id is None:
                    random_id = random_id_of(p.name) if random_id_of else 0
                extra.update(color=color, pass_index=pass_index, random_id=random_id, **_crypto(info),
                             **_catcher_holdout(info), **_ao_distance(info), **_light_group(info, groups))
            try:
                scene.add_points(p.points, p.radii, mat, matrix=m, **extra)
            except ValueError as e:  # inconsistent arrays: the cloud is left out, Blender goes on
                warn(f"Point cloud '{p.name}' not rendered: {e}")
                break


def core_camera(pc, params):
    """A pc.Camera with the fields `params`."""
    camera = pc.Camera()
    for name, value in params.items():
        setattr(camera, name, value)
    return camera


def set_camera(pc, scene, params):
    """Sets the camera of a core scene from pc.Camera fields `params`."""
    scene.set_camera(core_camera(pc, params))


# The light node trees' images each core scene holds, by content: lights sent again to a kept
# scene (replace_lights: viewport light edits, persistent-data frames) reuse them instead of
# adding them again (the core keeps every image it was given until the scene goes).
_LIGHT_IMAGES = weakref.WeakKeyDictionary()


def _light_image_ids(scene, images):
    from .core import get_core
    known = _LIGHT_IMAGES.setdefault(scene, {})
    ids = []
    for image in images:
        if getattr(image, "tiles", ()):  # a tile set: by its tiles' ids (added before it)
            tiles = [(n, ids[k]) for n, k in image.tiles]
            key = ("tiles", tuple(tiles))
            if key not in known:
                known[key] = scene.add_image_tiles(tiles)
            ids.append(known[key])
            continue
        px = np.ascontiguousarray(image.pixels)
        key = (get_core().hash_buffer(px, 0), px.shape, px.dtype.str, bool(image.srgb))
        if key not in known:
            known[key] = scene.add_image(image.pixels, srgb=image.srgb)
        ids.append(known[key])
    return ids


def add_lights(scene, lights, groups=()):
    """Adds LightData `lights` to a core scene; groups: the view layer's light group names
    (SceneData.light_groups) their Light Group is looked up in."""
    groups = list(groups)
    k = 0  # the core's index of the next analytic light (portals are not lights there)
    for light in lights:
        args = light.args
        images = getattr(light, "images", None)
        if images and args.get("shader") is not None:  # its node tree's images, then the program
            args = dict(args, shader=remap_images(args["shader"], _light_image_ids(scene, images)))
        getattr(scene, f"add_{light.kind}_light")(**args)  # (add-on and core ship together)
        if light.kind == "portal":
            continue
        if getattr(light, "links", None) is not None:
            scene.set_light_links(k, *light.links)
        g = group_index(groups, getattr(light, "lightgroup", ""))
        if g >= 0:  # (so never for older cores)
            scene.set_light_group(k, g)
        max_bounces = getattr(light, "max_bounces", 1024)
        if max_bounces < 1024:  # (only where set: the default reads nothing)
            scene.set_light_max_bounces(k, max_bounces)
        k += 1


def replace_lights(scene, lights, world, warn):
    """Replaces a committed core scene's lights (LightData) and world (`world`: what set_world
    reads of SceneData); its next commit() rebuilds only the light distribution."""
    scene.clear_lights()
    add_lights(scene, lights, getattr(world, "light_groups", None) or [])
    set_world(scene, world, warn)


def set_world(scene, data, warn):
    """Sets the world (texture or colour) of SceneData `data` on a core scene."""
    tex = data.world_texture
    program = getattr(data, "world_program", None)
    if program is not None:  # a node tree beyond the fast path's (its images, then the program)
        ops = remap_images(program.program, _light_image_ids(scene, program.images))
        scene.set_world_program(ops, program.width, program.height)
    elif isinstance(tex, WorldSky):
        setter = getattr(scene, f"set_world_{'sky' if tex.kind == 'nishita' else tex.kind}")
        setter(strength=tex.strength, rotation=tex.rotation, **tex.params)
    elif tex is not None and getattr(tex, "encoded", None) is not None:
        # An 8-bit sRGB image: the core filters the encoded values and decodes after (Cycles).
        scene.set_world_texture(tex.encoded, tex.strength, tex.rotation, srgb=True)
    elif tex is not None:
        scene.set_world_texture(tex.pixels, tex.strength, tex.rotation)
    else:
        scene.set_world_color(data.world_color)
    if hasattr(scene, "world_sampled"):  # World ▸ Settings ▸ Sampling Method (None: not a light)
        scene.world_sampled = bool(getattr(data, "world_sampled", True))
    volume = getattr(data, "world_volume", None)
    scene.set_world_volume(volume)
    g = group_index(list(getattr(data, "light_groups", None) or []), getattr(data, "world_lightgroup", ""))
    if g >= 0 or getattr(data, "light_groups", None):  # (so never for older cores without groups)
        scene.set_world_light_group(g)


def set_instance_transforms(scene, moves):
    """New matrices for instances of a committed core scene: `moves` is (instance index in
    add_instance order, (4, 4) float32 matrix) pairs. Its next commit() rebuilds the top level
    of the BVH (dynamic scenes) or the geometry of merged objects, and the lights."""
    for index, matrix in moves:
        scene.set_instance_transform(index, matrix)


def set_build_options(scene, **options):
    """Build options of a core scene (dynamic, spatial_splits, light_tree, ...) that its next
    commit() applies."""
    for name, value in options.items():
        setattr(scene, name, value)
