"""Images whose pixels depend on a tile or a frame: UDIM tiles ('TILED'), image sequences
('SEQUENCE') and movies ('MOVIE'). `image.pixels` only gives a tiled image's first tile and a
sequence's or movie's last loaded frame, so each tile or frame is read through a temporary
image (removed again) with the image's colour space and alpha mode: the same decoding as
Blender's own load, as Cycles reads them (its Blender sync: image_user_frame_number,
image_user_file_path, image_get_pixels_for_frame and the tile loaders). A movie's temporary
image is made to hold frame N by decode_movie_frame; decoded frames are cached."""

import os
import re
import tempfile
from collections import OrderedDict
from contextlib import contextmanager

import numpy as np

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


# Decoded movie frames, shared by every render of this Blender session: (file, its mtime and
# size, frame, colour space, alpha mode) -> (float32 (H, W, C) pixels, is_float), the most
# recently used last; at most MOVIE_CACHE_BYTES of pixels.
MOVIE_CACHE_BYTES = 256 << 20
_movie_frames = OrderedDict()


def clear_movie_cache():
    _movie_frames.clear()


def decode_movie_frame(tmp, frame):
    """Makes temporary movie image `tmp` hold movie frame `frame` (Blender's numbering: frame
    N is N - 1 of the file, clamped to the file's frames, as load_movie_single). bpy's
    image.pixels reads the buffer of the frame the image acquired last (ima->lastframe), and
    Image.scale(frame=N) acquires frame N through an ImageUser: scaled to its own size it is
    decoded and left unchanged, as Cycles' image_get_pixels_for_frame decodes it. Raises
    RuntimeError when the frame cannot be decoded."""
    width, height = tmp.size  # (decodes the first frame)
    if width * height == 0:
        raise RuntimeError("the movie has no readable frames")
    tmp.scale(width, height, frame=max(int(frame), 0))
    if tuple(tmp.size) != (width, height) or len(tmp.pixels) == 0:
        raise RuntimeError(f"frame {frame} has no pixels")


def _movie_key(image, path, frame):
    try:
        st = os.stat(path)
    except OSError:
        return None
    return (path, st.st_mtime_ns, st.st_size, frame, image.colorspace_settings.name, image.alpha_mode)


def _cached_frame(image, key):
    """A temporary image holding the cached pixels of `key` (None when not cached)."""
    import bpy
    got = _movie_frames.get(key)
    if got is None:
        return None
    _movie_frames.move_to_end(key)
    buf, is_float = got
    tmp = bpy.data.images.new(f"{image.name} frame {key[3]}", buf.shape[1], buf.shape[0],
                              alpha=True, float_buffer=is_float)
    try:
        _like(image, tmp)
        rgba = buf if buf.shape[2] == 4 else np.concatenate(
            [np.repeat(buf[..., :1], 3, axis=2) if buf.shape[2] < 3 else buf[..., :3],
             buf[..., 3:4] if buf.shape[2] in (2, 4) else np.ones(buf.shape[:2] + (1,), np.float32)],
            axis=2)
        tmp.pixels.foreach_set(np.ascontiguousarray(rgba, np.float32).ravel())
    except Exception:
        bpy.data.images.remove(tmp)
        raise
    return tmp


def _cache_frame(key, tmp):
    from .image import read_buffer
    buf, _ = read_buffer(tmp)
    if key is None or buf is None or buf.nbytes > MOVIE_CACHE_BYTES:
        return
    _movie_frames[key] = (buf, bool(tmp.is_float))
    total = sum(b.nbytes for b, _ in _movie_frames.values())
    while total > MOVIE_CACHE_BYTES:
        _, (old, _) = _movie_frames.popitem(last=False)
        total -= old.nbytes


@contextmanager
def frame_image(image, user, scene_frame):
    """A temporary image holding the frame of sequence or movie `image` that ImageUser `user`
    shows at `scene_frame` (user None: the file image.filepath names, a movie's first frame).
    Yields (image, None, note) or (None, why, None); note: what was approximated (a movie
    frame that cannot be decoded gives the movie's first frame)."""
    frame = image_frame(user, scene_frame) if user is not None else None
    path = _abspath(image, image.filepath)
    if image.source == 'SEQUENCE':
        label = "frame" if frame is None else f"frame {frame}"
        if frame is not None:
            path = sequence_path(path, frame)
        with _loaded(image, path, label) as (tmp, why):
            yield tmp, why, None
        return
    # A movie: frame N of its file, as Cycles reads it (frames up to 1 are the first, which a
    # fresh image holds; frame 0 is what an ImageUser of no frames gives).
    seek = frame is not None and frame > 1
    key = _movie_key(image, path, frame if seek else 1)
    cached = _cached_frame(image, key) if key is not None else None
    if cached is not None:
        try:
            yield cached, None, None
        finally:
            import bpy
            bpy.data.images.remove(cached)
        return
    with _loaded(image, path, "movie") as (tmp, why):
        if tmp is None:
            yield None, why, None
            return
        note = None
        if seek:
            try:
                decode_movie_frame(tmp, frame)
            except (RuntimeError, ValueError, TypeError) as e:
                note = (f"movie '{image.name}': frame {frame} cannot be decoded ({e}); "
                        "the movie's first frame is rendered")
        if note is None:
            _cache_frame(key, tmp)
            yield tmp, None, None
            return
    with _loaded(image, path, "movie") as (tmp, why):  # (afresh: the first frame)
        yield tmp, why, note if tmp is not None else None
