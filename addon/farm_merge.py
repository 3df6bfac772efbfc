"""Merging the pieces of a split frame inside Blender, so that a render farm can run the merge
as one more Blender task (tools/flamenco/pathlight_split_frame.js; docs/farm.md).

The same weighted mean as `build.py merge` for pieces rendered without adaptive sampling:
every pixel of piece k holds the mean of its n_k samples, so the frame is
sum(n_k * piece_k) / sum(n_k). Blender's image API cannot read EXR header attributes, so the
sample ranges come from the caller (the job script knows them) instead of the pieces'
metadata, and per-pixel Sample Count weights (adaptive renders) are `build.py merge`'s job.
Images are read and written as Non-Color, so that no colour transform touches the values
(tested: the written EXR is 32-bit float and equals `build.py merge`'s result).
"""

import bpy
import numpy as np


def frame_file(pattern, frame):
    """The file Blender writes for output `pattern` (--render-output) at `frame` as an EXR:
    Blender's own naming (a run of # is the zero-padded frame, the .exr extension added)."""
    r = bpy.context.scene.render
    fmt = r.image_settings
    saved = (r.filepath, fmt.file_format, fmt.color_depth, r.use_file_extension)
    try:
        r.filepath, fmt.file_format, r.use_file_extension = pattern, 'OPEN_EXR', True
        return bpy.path.abspath(r.frame_path(frame=frame))
    finally:
        r.filepath, fmt.file_format = saved[0], saved[1]
        fmt.color_depth, r.use_file_extension = saved[2], saved[3]


def _read(path):
    img = bpy.data.images.load(path, check_existing=False)
    try:
        img.colorspace_settings.name = 'Non-Color'  # the file's values, unconverted
        width, height = img.size
        if width == 0 or height == 0 or not img.is_float:
            raise ValueError(f"{path}: not a float image (render the pieces as OpenEXR)")
        pixels = np.empty(width * height * 4, np.float32)
        img.pixels.foreach_get(pixels)
        return (width, height), pixels
    finally:
        bpy.data.images.remove(img)


def merge_pieces(pieces, output, denoise=None):
    """pieces: [(path, sample_offset, samples)] of one frame; writes their sample-weighted mean
    to `output` (32-bit float RGBA OpenEXR). Refuses overlapping sample ranges (they would count
    samples twice) and pieces of different sizes. denoise: the scene's denoise settings
    (denoise.settings) or None; the pieces are not denoised (a partial range never is), so the
    merged frame is, here, from its colour alone (the RGBA pieces carry no albedo or normal).
    Returns the total number of samples."""
    if not pieces:
        raise ValueError("nothing to merge")
    ranges = sorted((int(o), int(n)) for _, o, n in pieces)
    if any(n < 1 or o < 0 for o, n in ranges):
        raise ValueError(f"sample ranges must be non-empty and start at >= 0: {ranges}")
    for (o1, n1), (o2, _) in zip(ranges, ranges[1:]):
        if o2 < o1 + n1:
            raise ValueError(f"sample ranges overlap: {ranges} would count samples twice")
    total, acc, size = 0, None, None
    for path, _, n in pieces:
        piece_size, pixels = _read(path)
        if acc is None:
            acc, size = np.zeros(pixels.size, np.float64), piece_size
        elif piece_size != size:
            raise ValueError(f"{path} is {piece_size[0]}x{piece_size[1]}, the first piece "
                             f"{size[0]}x{size[1]}")
        acc += int(n) * pixels.astype(np.float64)
        total += int(n)
    acc /= total
    if denoise is not None:
        acc = _denoise_merged(acc, size, denoise)
    img = bpy.data.images.new("Pathlight merge", size[0], size[1], alpha=True, float_buffer=True)
    try:
        img.colorspace_settings.name = 'Non-Color'
        img.pixels.foreach_set(acc.astype(np.float32))
        img.filepath_raw, img.file_format = output, 'OPEN_EXR'
        img.save()
    finally:
        bpy.data.images.remove(img)
    print(f"Saved: '{output}'")  # as Blender prints it: Flamenco's worker records the output
    return total


def _denoise_merged(pixels, size, opts):
    """The merged RGBA pixels (flat, Blender's order) denoised from their colour, or as they
    are, with a message, when Open Image Denoise is missing or fails."""
    from . import denoise as oidn
    image = pixels.astype(np.float32).reshape(size[1], size[0], 4)
    try:
        seconds = oidn.denoise(image, prefilter=opts["prefilter"], quality=opts["quality"])
    except (oidn.DenoiseError, ValueError) as e:
        print(f"Pathlight merge: not denoised: {e}")
        return pixels
    print(f"Pathlight merge: denoised the merged frame from its colour alone in {seconds:.2f} s "
          "(the pieces hold no albedo or normal)")
    return image.reshape(-1)


def merge_frame(frame, pieces, output_pattern):
    """merge_pieces for pieces given as output patterns: [(pattern, sample_offset, samples)]
    with the frame's files named as Blender names them. Returns the merged file's path."""
    if bpy.context.scene.render.use_multiview:
        # Blender's image API reads one view of a multiview EXR: the others would be lost.
        raise ValueError("the scene renders several views (Stereoscopy): merge its pieces with "
                         "`python3 build.py merge`, which keeps every view")
    output = frame_file(output_pattern, frame)
    from .denoise import settings
    merge_pieces([(frame_file(p, frame), o, n) for p, o, n in pieces], output,
                 denoise=settings(bpy.context.scene.pathlight))
    return output
