"""Images of the scene as the core's image table: each bpy Image read once, as Cycles stores
its texels."""

from dataclasses import dataclass, field

import numpy as np

from ..image import is_srgb_bytes, read_buffer, read_pixels, rgb_of, to_scene_linear

MISSING_TEXTURE = (1.0, 0.0, 1.0, 1.0)  # Cycles' magenta for an image that cannot be loaded


@dataclass
class ImageData:
    name: str
    pixels: np.ndarray  # float32 (H, W, 4) RGBA, row 0 = bottom: scene linear, or sRGB-encoded
    srgb: bool = False  # pixels hold sRGB-encoded colour, decoded by the core after filtering
    # A UDIM tile set (pixels None): (tile number, index of an earlier ImageData) pairs, the
    # core's add_image_tiles.
    tiles: tuple = ()


@dataclass
class _LoadedImage:
    assoc: np.ndarray  # float32 (H, W, 4): colour multiplied by alpha, as Cycles stores it
    has_alpha: bool  # any alpha below 1
    unassociate: bool = True  # False: colour and alpha independent (data, channel packed)
    srgb: bool = False  # assoc holds 8-bit sRGB-encoded colour (byte/255), associated in bytes
    indices: dict = field(default_factory=dict)  # variant -> index in ImageTable.images


@dataclass
class _LoadedTiles:
    """A tiled image: its readable tiles, each a _LoadedImage."""
    tiles: list  # (number, _LoadedImage)
    has_alpha: bool
    unassociate: bool
    indices: dict = field(default_factory=dict)


class ImageTable:
    """Images of the scene, each bpy Image read once (cached by pointer). Each variant of an
    image that programs use becomes one ImageData: "color" (the texels as Cycles stores them:
    associated alpha; the Color output divides by the filtered alpha when the Alpha output is
    linked, an operand of the image op) and "alpha" (the alpha in all four channels, so that it
    reads as a float register)."""

    def __init__(self):
        self.images = []  # ImageData, indexed by the program's image operands
        self._loaded = {}  # image pointer -> _LoadedImage or None (unreadable)
        # A tile set's index in images -> (material pointer, UV map name) of the one Image
        # Texture node that reads it, whose tiles cull_tiles may drop (export.udim_culling).
        self.tile_owners = {}

    def load(self, image, problems, user=None, frame=None):
        """_LoadedImage (_LoadedTiles for a tiled image) or None; what went wrong reading it is
        added to `problems` (at each call: each material using the image hears about it).
        user, frame: the node's ImageUser and the scene frame, which pick a sequence's or
        movie's frame (each frame is an image of its own here)."""
        key = image.as_pointer()
        if frame is None:
            user = None  # (no scene frame: the frame the image's path names)
        if image.source in {'SEQUENCE', 'MOVIE'} and user is not None:
            from ..image_sources import image_frame
            key = (key, image_frame(user, frame))
        if key not in self._loaded:
            notes = []
            self._loaded[key] = (_load_image(image, notes, user, frame), notes)
        loaded, notes = self._loaded[key]
        problems.extend(n for n in notes if n not in problems)
        return loaded

    def index(self, image, loaded, variant, owner=None):
        """The index in images of `variant` of `loaded`. owner (tile sets only): (material
        pointer, UV map name) of a node whose tiles Cycles culls by its material's meshes'
        UVs: that node gets a tile set of its own (its tiles' images are shared)."""
        key = variant if owner is None or not isinstance(loaded, _LoadedTiles) else (variant, owner)
        if key not in loaded.indices:
            if isinstance(loaded, _LoadedTiles):
                tiles = tuple((n, self.index(image, tile, variant)) for n, tile in loaded.tiles)
                loaded.indices[key] = len(self.images)
                suffix = "" if variant == "color" else f" ({variant})"
                self.images.append(ImageData(image.name + suffix, None, tiles=tiles))
                if key != variant:
                    self.tile_owners[loaded.indices[key]] = owner
                return loaded.indices[key]
            if variant == "alpha":
                a = loaded.assoc[..., 3:4]
                pixels, srgb = np.ascontiguousarray(np.repeat(a, 4, axis=2)), False
            else:
                pixels, srgb = loaded.assoc, loaded.srgb
            loaded.indices[variant] = len(self.images)
            suffix = "" if variant == "color" else f" ({variant})"
            self.images.append(ImageData(image.name + suffix, pixels, srgb))
        return loaded.indices[variant]


def _load_tiles(image, problems):
    """_LoadedTiles of tiled `image` (every tile of image.tiles: packed, generated or from its
    file), or None when it has none. Unreadable tiles are noted once, in one line, and read as
    Cycles reads them: one magenta texel (under the node's extension)."""
    from ..image_sources import UDIM_FIRST, UDIM_LAST, tile_image
    tiles, missing = [], []
    space = image.colorspace_settings
    srgb = not space.is_data and space.name == "sRGB"  # (as is_srgb_bytes)
    for tile in image.tiles:
        number = int(tile.number)
        if not UDIM_FIRST <= number <= UDIM_LAST:
            missing.append(f"{number} (not a UDIM tile number)")
            continue
        notes = []
        with tile_image(image, tile) as (tmp, why):
            loaded = _load_image(tmp, notes, buffer=True) if tmp is not None else None
        if loaded is None:  # Cycles' stand-in for an image it cannot load: 1 magenta texel,
            # a byte one (sRGB-encoded where the image's space is sRGB: filtered encoded)
            missing.append(why or "; ".join(notes) or str(number))
            loaded = _LoadedImage(np.array([[MISSING_TEXTURE]], np.float32), False, False, srgb)
        problems.extend(n for n in notes if n not in problems)
        tiles.append((number, loaded))
    if missing:
        problems.append(f"image '{image.name}': UDIM tiles that cannot be read render magenta "
                        f"(as Cycles): {'; '.join(missing)}")
    if not tiles:
        return _missing(f"image '{image.name}' has no UDIM tiles", problems)
    is_data = space.is_data or space.name == "Non-Color"
    unassociate = not is_data and image.alpha_mode not in {'CHANNEL_PACKED', 'NONE'}  # (as below)
    return _LoadedTiles(tiles, any(t.has_alpha for _, t in tiles), unassociate)


def _load_image(image, problems, user=None, frame=None, buffer=False):
    """_LoadedImage for a bpy Image, or None with a problem noted. Blender gives float images
    (.exr, .hdr) in scene linear with associated alpha, and byte images as raw byte/255 values
    in the image's colour space with straight alpha (image.pixels does not convert byte
    images). As Cycles does: byte sRGB images stay sRGB-encoded bytes, associated in bytes
    ((c * a) / 255, integer), for the core to filter encoded and decode per lookup; other
    byte images are linearised here and associated; data images are never associated."""
    if image.source == 'TILED' and not buffer:
        return _load_tiles(image, problems)
    if buffer:  # a temporary image of a tile
        buf, why = read_buffer(image)
    elif image.source in {'SEQUENCE', 'MOVIE'}:  # read through a temporary image of the frame
        from ..image_sources import frame_image
        with frame_image(image, user, frame) as (tmp, why, note):
            if note:
                problems.append(note)
            return _load_image(tmp, problems, buffer=True) if tmp is not None else _missing(why, problems)
    else:
        buf, why = read_pixels(image)
    if buf is None:
        return _missing(why, problems)
    height, width, channels = buf.shape
    rgb = rgb_of(buf)
    alpha = buf[..., 3] if channels == 4 else (buf[..., 1] if channels == 2 else None)
    alpha = np.ones((height, width), np.float32) if alpha is None else np.array(alpha)

    space = image.colorspace_settings
    is_data = space.is_data or space.name == "Non-Color"
    mode = image.alpha_mode
    associate = not is_data and mode not in {'CHANNEL_PACKED', 'NONE'}
    if is_srgb_bytes(image):
        to_byte = lambda x: np.clip(np.round(np.nan_to_num(x) * 255.0), 0, 255).astype(np.uint32)  # noqa: E731
        c, a = to_byte(rgb), to_byte(alpha)
        if mode == 'NONE':
            a[:] = 255
        if associate:
            c = c * a[..., None] // 255
        assoc = np.concatenate([c, a[..., None]], axis=2).astype(np.float32) / np.float32(255.0)
        return _LoadedImage(np.ascontiguousarray(assoc), bool((a < 255).any()), associate, True)

    rgb, note = to_scene_linear(image, rgb)
    if note:
        problems.append(note)
    # Byte images converted from a wide gamut keep their negative components, as Cycles keeps
    # OCIO's result (out-of-gamut colours); float images are clamped as before.
    keep_negative = is_data or not image.is_float
    bad = ~np.isfinite(rgb)
    if bad.any() or (rgb < 0).any() and not keep_negative:
        rgb = np.where(bad, 0.0, rgb)
        if not keep_negative:
            np.maximum(rgb, 0.0, out=rgb)
    alpha = np.clip(np.nan_to_num(alpha, nan=1.0), 0.0, 1.0)
    if mode == 'NONE':
        alpha[:] = 1.0
    if associate and not image.is_float:  # byte images are straight; float ones associated
        rgb = rgb * alpha[..., None]
    assoc = np.ascontiguousarray(np.concatenate([rgb, alpha[..., None]], axis=2), np.float32)
    return _LoadedImage(assoc, bool((alpha < 1.0).any()), associate)


def _missing(why, problems):
    problems.append(why + " (magenta)")
