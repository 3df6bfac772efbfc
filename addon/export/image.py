"""Reading Blender images into numpy, shared by textures and the world: the pixels (row 0 =
bottom, as image.pixels gives them) and their conversion to scene linear."""

import numpy as np

# Byte-image colour spaces whose values are already linear.
LINEAR_SPACES = {"Linear Rec.709", "Non-Color", "Raw", "Linear", "Linear Rec.709 (sRGB)"}


def srgb_to_linear(c):
    """The sRGB transfer function (IEC 61966-2-1), as OCIO applies it for 'sRGB' images."""
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


def read_pixels(image, user=None, frame=None, notes=None):
    """float32 (H, W, C) pixels of a bpy Image with C in 1..4, or (None, why) if it has none.
    Returns (pixels, None) on success. Sequences and movies: the frame ImageUser `user` shows
    at scene frame `frame` (user None: the file image.filepath names; image_sources.py);
    `notes` (a list) hears what was approximated."""
    if image.source in {'SEQUENCE', 'MOVIE'}:
        from .image_sources import frame_image
        with frame_image(image, user, frame) as (tmp, why, note):
            if note and notes is not None:
                notes.append(note)
            return (None, why) if tmp is None else read_buffer(tmp)
    if image.source not in {'FILE', 'GENERATED'}:
        return None, f"image '{image.name}' of type {image.source} is not supported"
    return read_buffer(image)


def read_buffer(image):
    """read_pixels of the buffer Blender holds for `image` now, whatever its source."""
    try:
        width, height = image.size  # loads the image (packed or external) on first access
        n = len(image.pixels)
    except (RuntimeError, ReferenceError):
        width = height = n = 0
    channels = n // max(width * height, 1)
    if width * height == 0 or n != width * height * channels or channels not in (1, 2, 3, 4):
        return None, f"image '{image.name}' cannot be read (missing file '{image.filepath}'?)"
    buf = np.empty(n, np.float32)
    image.pixels.foreach_get(buf)
    return buf.reshape(height, width, channels), None


def rgb_of(buf):
    """The RGB channels of read_pixels' result (grey images repeated to three channels)."""
    return np.repeat(buf[..., :1], 3, axis=2) if buf.shape[2] < 3 else np.ascontiguousarray(buf[..., :3])


def is_srgb_bytes(image):
    """True for a byte image that Cycles keeps sRGB-encoded (filtered before decoding): a byte
    image in the sRGB space. Byte images in other spaces are converted to scene linear at load
    (to_scene_linear), as Cycles converts them with OpenColorIO."""
    space = image.colorspace_settings
    return not (image.is_float or space.is_data) and space.name == "sRGB"


def to_scene_linear(image, rgb):
    """Blender gives float images (.exr, .hdr) already in scene linear and byte images as raw
    byte/255 values in the image's colour space, linearised here as Cycles does: sRGB by its
    transfer function, other spaces by OpenColorIO with Blender's config (ocio.py).
    Returns (rgb, note or None) where the note names a colour space this cannot convert and why
    (the bindings missing, or no processor for it; then decoded as sRGB)."""
    space = image.colorspace_settings
    if image.is_float or space.is_data or space.name == "Non-Color" or space.name in LINEAR_SPACES:
        return rgb, None
    if space.name == "sRGB":
        return srgb_to_linear(rgb), None
    from .ocio import Unsupported, to_scene_linear as ocio_to_scene_linear
    try:
        return ocio_to_scene_linear(rgb, space.name), None
    except (Unsupported, OSError) as e:
        return srgb_to_linear(rgb), (f"colour space '{space.name}' of byte image '{image.name}' is "
                                     f"not supported ({e}; decoded as sRGB)")
