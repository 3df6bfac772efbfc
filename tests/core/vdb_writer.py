"""A minimal OpenVDB (.vdb, file format 224) writer for the reader's tests (issue 23): one or more
grids of float / double / vec3s / int32 / bool values as a 5-4-3 tree, with the codecs OpenVDB
writes (none, ZIP, Blosc 1 with LZ4 and byte shuffle), active-mask compression with every
per-node metadata kind, and half-float storage. Written from the format's public description;
no OpenVDB needed. Also a small LZ4 block compressor and Blosc 1 frame writer."""
import struct
import zlib

import numpy as np

ZIP, ACTIVE_MASK, BLOSC = 0x1, 0x2, 0x4
DTYPES = {"float": ("<f4", 1), "double": ("<f8", 1), "vec3s": ("<f4", 3), "int32": ("<i4", 1),
          "bool": ("u1", 1)}


def lz4_compress(data: bytes) -> bytes:
    """A greedy LZ4 block (hash of 4 bytes -> last position): valid per the block format, with
    the last 5 bytes as literals and no match starting within 12 bytes of the end."""
    n, out, anchor, i, table = len(data), bytearray(), 0, 0, {}

    def length_bytes(v):
        b = bytearray()
        while v >= 255:
            b.append(255)
            v -= 255
        b.append(v)
        return b

    def emit(lit, match_len, offset):
        tok_l = min(len(lit), 15)
        tok_m = 0 if match_len is None else min(match_len - 4, 15)
        out.append(tok_l << 4 | tok_m)
        if len(lit) >= 15:
            out.extend(length_bytes(len(lit) - 15))
        out.extend(lit)
        if match_len is not None:
            out.extend(struct.pack("<H", offset))
            if match_len - 4 >= 15:
                out.extend(length_bytes(match_len - 4 - 15))

    while i + 12 <= n:
        key = data[i:i + 4]
        j = table.get(key)
        table[key] = i
        if j is not None and i - j <= 65535:
            m = 4
            while i + m < n - 5 and data[j + m] == data[i + m]:
                m += 1
            emit(data[anchor:i], m, i - j)
            i += m
            anchor = i
        else:
            i += 1
    emit(data[anchor:], None, 0)
    return bytes(out)


def shuffle(block: bytes, typesize: int) -> bytes:
    n = len(block) // typesize
    head = np.frombuffer(block[:n * typesize], np.uint8).reshape(n, typesize).T.tobytes()
    return head + block[n * typesize:]


def blosc_frame(data: bytes, typesize: int, blocksize=None, do_shuffle=True, split=False, memcpy=False,
                compress=True) -> bytes:
    """A Blosc 1 frame (LZ4 codec): split=True writes one stream per byte of the type (the old
    layout, flag 0x10 clear) where blosc would; memcpy=True stores the data uncompressed."""
    nbytes = len(data)
    blocksize = min(blocksize or nbytes, nbytes) or 1
    flags = (1 << 5) | (1 if do_shuffle else 0)
    if memcpy:
        flags |= 0x2
        return struct.pack("<BBBBIII", 2, 1, flags, typesize, nbytes, blocksize, 16 + nbytes) + data
    if not split:
        flags |= 0x10
    nblocks = -(-nbytes // blocksize)
    body, starts = bytearray(), []
    head = 16 + 4 * nblocks
    for b in range(nblocks):
        block = data[b * blocksize:(b + 1) * blocksize]
        leftover = len(block) < blocksize
        if do_shuffle and typesize > 1:
            block = shuffle(block, typesize)
        nsplit = typesize if (split and typesize <= 16 and blocksize // typesize >= 128 and not leftover) else 1
        neb = len(block) // nsplit
        starts.append(head + len(body))
        for s in range(nsplit):
            part = block[s * neb:(s + 1) * neb]
            c = lz4_compress(part) if compress else part
            if len(c) >= neb:
                c = part
            body += struct.pack("<i", len(c)) + c
    total = head + len(body)
    return struct.pack("<BBBBIII", 2, 1, flags, typesize, nbytes, blocksize, total) + \
        b"".join(struct.pack("<I", s) for s in starts) + bytes(body)


def _string(s):
    b = s.encode() if isinstance(s, str) else s
    return struct.pack("<I", len(b)) + b


def _first_distinct(rows, limit):
    """The first `limit` distinct rows in order of first occurrence, compared with == (as
    np.array_equal: -0 equals 0, a NaN equals nothing, so every row with a NaN is new): what
    a loop over the rows keeping those unlike all kept so far gives, in a few vector operations
    per kept row instead of numpy calls per row (an internal node has 32768 values). More than
    two distinct rows all mean the same (metadata 6), so `limit` 3 is enough."""
    distinct = []
    while len(rows) and len(distinct) < limit:
        v = rows[0]
        distinct.append(v)
        keep = ~np.all(rows == v, axis=1)
        keep[0] = False
        rows = rows[keep]
    return distinct


class Grid:
    """A grid to write. leaves: {(x, y, z) origin (multiple of 8): (values [8,8,8(,3)], active
    bool [8,8,8])}; tiles: [(size 8|128|4096, origin, value, active)]."""

    def __init__(self, name="density", value_type="float", background=0.0, codec="none",
                 active_mask=True, half=False, transform=("UniformScaleMap", 0.5), metadata=None):
        self.name, self.value_type, self.background = name, value_type, background
        self.codec, self.active_mask, self.half = codec, active_mask, half
        self.transform, self.leaves, self.tiles = transform, {}, []
        self.metadata = metadata or {}
        self.node_metadata = []  # the per-node metadata bytes written, for the tests

    # ---- values
    def _dtype(self):
        return DTYPES[self.value_type]

    def _vals(self, arr, half):
        dt, nc = self._dtype()
        a = np.asarray(arr)
        if half:
            return a.astype("<f2").tobytes()
        return a.astype(dt).tobytes()

    def _one(self, v):
        return self._vals(np.asarray(v, dtype=float).reshape(-1)[:self._dtype()[1]], False)

    def _data(self, raw: bytes, typesize: int) -> bytes:
        if self.codec == "none":
            return raw
        if self.codec == "zip":
            return struct.pack("<q", len(zlib.compress(raw))) + zlib.compress(raw)
        if self.codec == "zip-raw":  # ZIP grid, block stored uncompressed (negative size)
            return struct.pack("<q", -len(raw)) + raw
        frame = blosc_frame(raw, typesize, **self.blosc_args)
        return struct.pack("<q", len(frame)) + frame

    blosc_args = {}

    def compression(self):
        c = {"none": 0, "zip": ZIP, "zip-raw": ZIP, "blosc": BLOSC}[self.codec]
        return c | (ACTIVE_MASK if self.active_mask else 0)

    def _compressed_values(self, values, active):
        """writeCompressedValues: metadata byte, inactive values, selection mask, the data."""
        dt, nc = self._dtype()
        vals = np.asarray(values, dtype=float).reshape(len(active), nc)
        bg = np.asarray(self.background, dtype=float).reshape(-1)[:nc]
        out = bytearray()
        half = self.half and self.value_type in ("float", "double", "vec3s")
        if not self.active_mask:
            meta, stored = 6, vals
        else:
            distinct = _first_distinct(vals[~active], 3)
            sel = np.zeros(len(active), bool)
            extra = []
            if len(distinct) == 0 or (len(distinct) == 1 and np.array_equal(distinct[0], bg)):
                meta = 0
            elif len(distinct) == 1 and np.array_equal(distinct[0], -bg):
                meta = 1
            elif len(distinct) == 1:
                meta, extra = 2, [distinct[0]]
            elif len(distinct) == 2 and any(np.array_equal(d, bg) for d in distinct):
                other = distinct[0] if not np.array_equal(distinct[0], bg) else distinct[1]
                sel = ~active & np.all(vals == bg, axis=1)
                meta, extra = (3, []) if np.array_equal(other, -bg) else (4, [other])
            elif len(distinct) == 2:
                sel = ~active & np.all(vals == distinct[1], axis=1)
                meta, extra = 5, [distinct[0], distinct[1]]
            else:
                meta = 6
            stored = vals if meta == 6 else vals[active]
            self.node_metadata.append(meta)
            out.append(meta)
            for e in extra:
                out += self._one(e)
            if meta in (3, 4, 5):
                out += np.packbits(sel, bitorder="little").tobytes()
            raw = self._vals(stored, half)
            return bytes(out) + self._data(raw, (2 if half else np.dtype(dt).itemsize) * nc)
        self.node_metadata.append(meta)
        out.append(meta)
        raw = self._vals(stored, half)
        return bytes(out) + self._data(raw, (2 if half else np.dtype(dt).itemsize) * nc)

    # ---- tree
    def _tree(self):
        dt, nc = self._dtype()
        leaves = {tuple(int(c) for c in o): v for o, v in self.leaves.items()}
        root_tiles = [t for t in self.tiles if t[0] == 4096]
        i5 = {}
        for o in leaves:
            i5.setdefault(tuple(c & ~4095 for c in o), set()).add(tuple(c & ~127 for c in o))
        for size, o, v, a in self.tiles:
            if size == 128:
                i5.setdefault(tuple(c & ~4095 for c in o), set())
            if size == 8:
                i5.setdefault(tuple(c & ~4095 for c in o), set()).add(tuple(c & ~127 for c in o))
        return leaves, root_tiles, i5

    def _mask(self, bits):
        return np.packbits(np.asarray(bits, bool), bitorder="little").tobytes()

    def _internal_topology(self, origin, log2, child_log2, leaves, i4s):
        n = 1 << (3 * log2)
        child = np.zeros(n, bool)
        active = np.zeros(n, bool)
        nc = self._dtype()[1]
        values = np.tile(np.asarray(self.background, dtype=float).reshape(-1)[:nc], (n, 1))
        dim = 1 << log2

        def index(o):
            x, y, z = ((o[a] - origin[a]) >> child_log2 for a in range(3))
            return (x << (2 * log2)) + (y << log2) + z
        kids = {}
        tile_size = 1 << child_log2
        for size, o, v, a in self.tiles:
            if size == tile_size and all(origin[k] <= o[k] < origin[k] + (dim << child_log2) for k in range(3)):
                values[index(o)] = np.asarray(v, dtype=float).reshape(-1)[:nc]
                active[index(o)] = a
        children = leaves if child_log2 == 3 else i4s
        for o in children:
            if all(origin[k] <= o[k] < origin[k] + (dim << child_log2) for k in range(3)):
                child[index(o)] = True
                kids[index(o)] = o
        out = self._mask(child) + self._mask(active) + self._compressed_values(values, active)
        order = []
        for idx in sorted(kids):
            o = kids[idx]
            if child_log2 == 3:
                out += self._mask(leaves[o][1].reshape(-1))
                order.append(o)
            else:
                t, sub = self._internal_topology(o, 4, 3, leaves, i4s)
                out += t
                order += sub
        return out, order

    def serialize(self):
        """The grid's bytes from the compression flags on (gridPos) and the offset of its buffers."""
        dt, nc = self._dtype()
        out = bytearray(struct.pack("<I", self.compression()))
        meta = dict(self.metadata)
        meta.setdefault("class", ("string", b"fog volume"))
        meta.setdefault("name", ("string", self.name.encode()))
        if self.half:
            meta["is_saved_as_half_float"] = ("bool", b"\x01")
        out += struct.pack("<I", len(meta))
        for k, (t, v) in meta.items():
            out += _string(k) + _string(t) + struct.pack("<I", len(v)) + v
        kind, *args = self.transform
        out += _string(kind)
        if kind in ("UniformScaleMap", "ScaleMap"):
            s = np.broadcast_to(np.asarray(args[0], float), 3)
            with np.errstate(divide="ignore"):
                out += np.concatenate([s, s, 1 / s, 1 / s ** 2, 0.5 / s]).astype("<f8").tobytes()
        elif kind in ("UniformScaleTranslateMap", "ScaleTranslateMap"):
            s = np.broadcast_to(np.asarray(args[0], float), 3)
            t = np.asarray(args[1], float)
            out += np.concatenate([t, s, s, 1 / s, 1 / s ** 2, 0.5 / s]).astype("<f8").tobytes()
        elif kind == "TranslationMap":
            out += np.asarray(args[0], "<f8").tobytes()
        elif kind in ("AffineMap", "UnitaryMap"):
            out += np.asarray(args[0], "<f8").reshape(4, 4).tobytes()  # row-vector convention
        else:
            out += bytes(args[0])
        out += struct.pack("<i", 1)
        out += self._one(self.background)
        leaves, root_tiles, i5 = self._tree()
        out += struct.pack("<II", len(root_tiles), len(i5))
        for size, o, v, a in root_tiles:
            out += struct.pack("<3i", *o) + self._one(v) + bytes([1 if a else 0])
        i4s = set().union(*i5.values()) if i5 else set()
        order = []
        for o in sorted(i5):
            t, sub = self._internal_topology(o, 5, 7, leaves, i4s)
            out += struct.pack("<3i", *o) + t
            order += sub
        block = len(out)
        for o in order:
            vals, act = leaves[o]
            out += self._mask(act.reshape(-1))
            if self.value_type == "bool":
                out += struct.pack("<3i", *o) + self._mask(np.asarray(vals, bool).reshape(-1))
            else:
                out += self._compressed_values(np.asarray(vals, float).reshape(512, -1), act.reshape(-1))
        return bytes(out), block


def write_vdb(grids, version=224) -> bytes:
    out = bytearray(struct.pack("<qI", 0x56444220, version))
    out += struct.pack("<II", 12, 0) + b"\x01" + b"01234567-89ab-cdef-0123-456789abcdef"
    out += struct.pack("<I", 0)  # file metadata
    out += struct.pack("<i", len(grids))
    for g in grids:
        tree_type = f"Tree_{g.value_type}_5_4_3" + ("_HalfFloat" if g.half else "")
        desc = _string(g.name) + _string(tree_type) + _string("")
        body, block = g.serialize()
        grid_pos = len(out) + len(desc) + 24
        out += desc + struct.pack("<qqq", grid_pos, grid_pos + block, grid_pos + len(body)) + body
    return bytes(out)
