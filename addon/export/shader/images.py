"""Images of the scene as the core's image table: each bpy Image read once, as Cycles stores
its texels."""

from dataclasses import dataclass, field

import numpy as np

from ..image import is_srgb_bytes, read_pixels, rgb_of, to_scene_linear

MISSING_TEXTURE = (1.0, 0.0, 1.0, 1.0)  # Cycles' magenta for an image that cannot be loaded


@dataclass
class ImageData:
    name: str
    pixels: np.ndarray  # float32 (H, W, 4) RGBA, row 0 = bottom: scene linear, or sRGB-encoded
    srgb: bool = False  # pixels hold sRGB-encoded colour, decoded by the core after filtering


@dataclass
class _LoadedImage:
    assoc: np.ndarray  # float32 (H, W, 4): colour multiplied by alpha, as Cycles stores it
    has_alpha: bool  # any alpha below 1
    unassociate: bool = True  # False: colour and alpha independent (data, channel packed)
    srgb: bool = False  # assoc holds 8-bit sRGB-encoded colour (byte/255), associated in bytes
    indices: dict = field(default_factory=dict)  # variant -> index in ImageTable.images


class ImageTable:
    """Images of the scene, each bpy Image read once (cached by pointer). Each variant of an
    image that programs use becomes one ImageData: "color" (the texels as Cycles stores them:
    associated alpha; the Color output divides by the filtered alpha when the Alpha output is
    linked, an operand of the image op) and "alpha" (the alpha in all four channels, so that it
    reads as a float register)."""

    def __init__(self):
        self.images = []  # ImageData, indexed by the program's image operands
        self._loaded = {}  # image pointer -> _LoadedImage or None (unreadable)

    def load(self, image, problems):
        """_LoadedImage or None; what went wrong reading it is added to `problems` (at each
        call: each material using the image hears about it)."""
        key = image.as_pointer()
        if key not in self._loaded:
            notes = []
            self._loaded[key] = (_load_image(image, notes), notes)
        loaded, notes = self._loaded[key]
        problems.extend(n for n in notes if n not in problems)
        return loaded

    def index(self, image, loaded, variant):
        if variant not in loaded.indices:
            if variant == "alpha":
                a = loaded.assoc[..., 3:4]
                pixels, srgb = np.ascontiguousarray(np.repeat(a, 4, axis=2)), False
            else:
                pixels, srgb = loaded.assoc, loaded.srgb
            loaded.indices[variant] = len(self.images)
            suffix = "" if variant == "color" else f" ({variant})"
            self.images.append(ImageData(image.name + suffix, pixels, srgb))
        return loaded.indices[variant]


def _load_image(image, problems):
    """_LoadedImage for a bpy Image, or None with a problem noted. Blender gives float images
    (.exr, .hdr) in scene linear with associated alpha, and byte images as raw byte/255 values
    in the image's colour space with straight alpha (image.pixels does not convert byte
    images). As Cycles does: byte sRGB images stay sRGB-encoded bytes, associated in bytes
    ((c * a) / 255, integer), for the core to filter encoded and decode per lookup; other
    byte images are linearised here and associated; data images are never associated."""
    buf, why = read_pixels(image)
    if buf is None:
        problems.append(why + " (magenta)")
        return None
    height, width, channels = buf.shape
    rgb = rgb_of(buf)
    alpha = buf[..., 3] if channels == 4 else (buf[..., 1] if channels == 2 else None)
    alpha = np.ones((height, width), np.float32) if alpha is None else np.array(alpha)

    space = image.colorspace_settings
    is_data = space.is_data or space.name == "Non-Color"
    mode = image.alpha_mode
    associate = not is_data and mode not in {'CHANNEL_PACKED', 'NONE'}
    if is_srgb_bytes(image):
        if space.name != "sRGB":
            problems.append(f"colour space '{space.name}' of byte image '{image.name}' is not "
                            "supported (decoded as sRGB)")
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
    bad = ~np.isfinite(rgb)
    if bad.any() or (rgb < 0).any() and not is_data:
        rgb = np.where(bad, 0.0, rgb)
        if not is_data:
            np.maximum(rgb, 0.0, out=rgb)
    alpha = np.clip(np.nan_to_num(alpha, nan=1.0), 0.0, 1.0)
    if mode == 'NONE':
        alpha[:] = 1.0
    if associate and not image.is_float:  # byte images are straight; float ones associated
        rgb = rgb * alpha[..., None]
    assoc = np.ascontiguousarray(np.concatenate([rgb, alpha[..., None]], axis=2), np.float32)
    return _LoadedImage(assoc, bool((alpha < 1.0).any()), associate)
