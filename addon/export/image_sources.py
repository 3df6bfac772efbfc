"""Images whose pixels depend on a tile or a frame: UDIM tiles ('TILED'), image sequences
('SEQUENCE') and movies ('MOVIE'). `image.pixels` only gives a tiled image's first tile and a
sequence's or movie's last loaded frame, so each tile or frame is read through a temporary
image (removed again) with the image's colour space and alpha mode: the same decoding as
Blender's own load, as Cycles reads them (its Blender sync: image_user_frame_number,
image_user_file_path and the tile loaders)."""

import os
import re
import tempfile
from contextlib import contextmanager

UDIM_FIRST, UDIM_LAST = 1001, 2000  # Blender's tile numbers: 1001 + u + 10 v, u in 0..9


def image_frame(user, scene_frame):
    """The frame of an animated image that ImageUser `user` shows at scene frame `scene_frame`:
    Blender's BKE_image_user_frame_get (Frames, Start Frame, Offset, Cyclic). Cycles computes it
    at every render whether or not Auto Refresh is on, so this does too."""
    length = int(user.frame_duration)
    if length == 0:
        return 0
    cyclic = bool(user.use_cyclic)
    cfra = int(scene_frame) - int(user.frame_start) + 1
    if cyclic:
        cfra %= length  # (Python's % is never negative: C's `if (cfra < 0) cfra += len`)
        if cfra == 0:
            cfra = length
    cfra = min(max(cfra, 0), length)
    frame = cfra
    if cyclic:
        frame %= length
        if frame == 0:
            frame = length
    return frame + int(user.frame_offset)


def sequence_path(path, frame):
    """`path` with the last run of digits of its file name (before the extension) replaced by
    `frame`, zero-padded to as many digits (BLI_path_sequence_decode / _encode). A name
    without digits gets the frame before the extension."""
    head, name = os.path.split(path)
    stem, dot, ext = name.rpartition(".")
    if not dot or not stem:
        stem, ext = name, ""
    else:
        ext = "." + ext
    match = None
    for match in re.finditer(r"\d+", stem):
        pass
    frame = max(int(frame), 0)
    if match is None:  # (C's "%.0d" prints nothing for 0)
        return os.path.join(head, f"{stem}{frame or ''}{ext}")
    digits = match.end() - match.start()
    return os.path.join(head, f"{stem[:match.start()]}{frame:0{digits}d}{stem[match.end():]}{ext}")


def tile_path(path, number):
    """A tiled image's path with the tile's number in place of <UDIM> (1001) or <UVTILE>
    (u1_v1), as Cycles' ImageManager substitutes them."""
    u, v = (number - 1001) % 10, (number - 1001) // 10
    return path.replace("<UDIM>", f"{number:04d}").replace("<UVTILE>", f"u{u + 1}_v{v + 1}")


def _abspath(image, path):
    import bpy
    return os.path.normpath(bpy.path.abspath(path, library=image.library))


def _like(image, tmp):
    """Gives temporary image `tmp` the colour decoding of `image` (before its pixels load)."""
    try:
        tmp.colorspace_settings.name = image.colorspace_settings.name
    except TypeError:  # a space this config lacks: keep the file's default
        pass
    tmp.alpha_mode = image.alpha_mode


@contextmanager
def _loaded(image, path, label):
    """A temporary image of file `path` decoded like `image`: yields (image, None), or
    (None, why) when the file is missing or unreadable."""
    import bpy
    if not os.path.isfile(path):
        yield None, f"image '{image.name}': {label} file '{path}' not found"
        return
    try:
        tmp = bpy.data.images.load(path, check_existing=False)
    except RuntimeError as e:
        yield None, f"image '{image.name}': {label} file '{path}' cannot be read ({e})"
        return
    try:
        _like(image, tmp)
        yield tmp, None
    finally:
        bpy.data.images.remove(tmp)


@contextmanager
def tile_image(image, tile):
    """A temporary image holding UDIMTile `tile` of tiled image `image` (packed, generated, or
    read from the tile's file): yields (image, None) or (None, why)."""
    import bpy
    number = int(tile.number)
    label = f"UDIM tile {number}"
    packed = next((p for p in image.packed_files if int(getattr(p, "tile_number", 0)) == number), None)
    if packed is not None:
        ext = os.path.splitext(packed.filepath)[1] or ".png"
        fd, path = tempfile.mkstemp(suffix=ext, prefix="pathlight_tile_")
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(packed.packed_file.data)
            with _loaded(image, path, label) as got:
                yield got
        finally:
            os.unlink(path)
        return
    if tile.is_generated_tile:
        w, h = int(tile.generated_width), int(tile.generated_height)
        tmp = bpy.data.images.new(f"{image.name} {number}", w, h, alpha=True,
                                  float_buffer=bool(tile.use_generated_float))
        try:
            tmp.generated_type = tile.generated_type
            tmp.generated_color = tile.generated_color
            _like(image, tmp)
            yield tmp, None
        finally:
            bpy.data.images.remove(tmp)
        return
    if not image.filepath:
        yield None, f"image '{image.name}': {label} has no file (unsaved)"
        return
    with _loaded(image, tile_path(_abspath(image, image.filepath), number), label) as got:
        yield got


@contextmanager
def frame_image(image, user, scene_frame):
    """A temporary image holding the frame of sequence or movie `image` that ImageUser `user`
    shows at `scene_frame` (user None: the file image.filepath names). Yields (image, None,
    note) or (None, why, None); note: what was approximated (a movie gives its first frame)."""
    frame = image_frame(user, scene_frame) if user is not None else None
    path = _abspath(image, image.filepath)
    note = None
    if image.source == 'SEQUENCE':
        label = "frame" if frame is None else f"frame {frame}"
        if frame is not None:
            path = sequence_path(path, frame)
    else:
        # bpy reads a movie's frames only through image.pixels, which gives the frame Blender
        # loaded last: a freshly loaded copy gives the first frame (Blender's movie frame N is
        # N - 1 of the file, clamped to it).
        label = "movie"
        if frame is not None and frame > 1:
            note = (f"movie '{image.name}': frame {frame} is rendered as the movie's first frame "
                    "(reading movie frames is not supported yet)")
    with _loaded(image, path, label) as (tmp, why):
        yield tmp, why, note if tmp is not None else None
