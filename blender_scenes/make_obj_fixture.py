"""Write the OBJ+MTL fixture of issue 3 into blender_scenes/obj_materials/ (plain Python, no
Blender needed):

    python3 blender_scenes/make_obj_fixture.py

obj_materials/model.obj + model.mtl + checker.png: three objects, one material each, as an
artist's OBJ export would have them (Z up as Blender's importer expects with its default
axes: -Z forward, Y up in the file):

- "Floor": a 3 m textured quad (UVs 0..2, so the texture repeats twice), material `checker`
  with `map_Kd checker.png`: a 4x4 PNG of four distinct colours.
- "Glass": an icosphere (radius 0.5) with material `glass`: Ni 1.5 and Tf 1 1 1 (Blender's
  importer makes Transmission Weight 1 of Tf), Ns 1000 (roughness 0), illum 2. Note what the
  importer does with the other "glass" spellings: illum 4..7 become Metallic 1 (a mirror,
  not glass) and `d` becomes Alpha (a mix with Transparent), so they are not used here.
- "Shiny": a cube with material `shiny`: a blue Kd with Ks 0.5 and Ns 200 (Principled with
  Specular IOR Level 0.5, roughness about 0.55).
"""

import math
import struct
import zlib
from pathlib import Path

OUT = Path(__file__).resolve().parent / "obj_materials"

# Texel colours (sRGB bytes), row 0 = top of the image as stored in the PNG.
TEXTURE = [
    [(230, 40, 40), (240, 200, 40), (230, 40, 40), (240, 200, 40)],
    [(40, 90, 220), (40, 180, 80), (40, 90, 220), (40, 180, 80)],
    [(230, 40, 40), (240, 200, 40), (230, 40, 40), (240, 200, 40)],
    [(40, 90, 220), (40, 180, 80), (40, 90, 220), (40, 180, 80)],
]


def png_bytes(rows):
    """An 8-bit RGB PNG of rows of (r, g, b) tuples."""
    h, w = len(rows), len(rows[0])
    raw = b"".join(b"\x00" + bytes(c for px in row for c in px) for row in rows)

    def chunk(kind, data):
        return (struct.pack(">I", len(data)) + kind + data
                + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))
    return (b"\x89PNG\r\n\x1a\n"
            + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def icosphere(radius, subdivisions=2):
    t = (1 + math.sqrt(5)) / 2
    verts = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t),
             (0, -1, -t), (0, 1, -t), (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
             (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
             (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    verts = [tuple(c / math.sqrt(sum(x * x for x in v)) for c in v) for v in verts]
    for _ in range(subdivisions):
        cache = {}

        def mid(a, b):
            key = (min(a, b), max(a, b))
            if key not in cache:
                m = [(x + y) / 2 for x, y in zip(verts[a], verts[b])]
                n = math.sqrt(sum(x * x for x in m))
                verts.append(tuple(x / n for x in m))
                cache[key] = len(verts) - 1
            return cache[key]
        new = []
        for a, b, c in faces:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            new += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new
    return [tuple(radius * x for x in v) for v in verts], faces


def to_file(p):
    """Blender (x, y, z) → OBJ file axes for the default import (-Z forward, Y up)."""
    x, y, z = p
    return (x, z, -y)


def write():
    OUT.mkdir(exist_ok=True)
    (OUT / "checker.png").write_bytes(png_bytes(TEXTURE))
    (OUT / "model.mtl").write_text("""# Pathlight issue 3 fixture (blender_scenes/make_obj_fixture.py)
newmtl checker
Ka 0 0 0
Kd 1 1 1
Ks 0 0 0
Ns 10
illum 1
map_Kd checker.png

newmtl glass
Kd 1 1 1
Ks 1 1 1
Ns 1000
Ni 1.5
Tf 1 1 1
illum 2

newmtl shiny
Kd 0.1 0.3 0.6
Ks 0.5 0.5 0.5
Ns 200
illum 2
""")
    lines = ["# Pathlight issue 3 fixture (blender_scenes/make_obj_fixture.py)", "mtllib model.mtl"]
    v_count = vt_count = 0

    def add_vertices(points):
        nonlocal v_count
        lines.extend("v %.6f %.6f %.6f" % to_file(p) for p in points)
        v_count += len(points)
        return v_count - len(points) + 1  # 1-based index of the first

    # Floor: 3 m quad at z = 0, UVs 0..2.
    base = add_vertices([(-1.5, -1.5, 0), (1.5, -1.5, 0), (1.5, 1.5, 0), (-1.5, 1.5, 0)])
    lines += ["vt 0 0", "vt 2 0", "vt 2 2", "vt 0 2"]
    vt_count += 4
    lines += ["o Floor", "usemtl checker",
              "f %d/1 %d/2 %d/3 %d/4" % (base, base + 1, base + 2, base + 3)]
    # Glass: icosphere resting on the floor.
    verts, faces = icosphere(0.5, 2)
    base = add_vertices([(x - 0.45, y - 0.2, z + 0.5) for x, y, z in verts])
    lines += ["o Glass", "usemtl glass"]
    lines += ["f %d %d %d" % tuple(base + i for i in f) for f in faces]
    # Shiny: a 0.7 m cube, turned a little.
    c, s = math.cos(0.5), math.sin(0.5)
    corners = [(x, y, z) for z in (0, 0.7) for y in (-0.35, 0.35) for x in (-0.35, 0.35)]
    base = add_vertices([(c * x - s * y + 0.6, s * x + c * y + 0.35, z) for x, y, z in corners])
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    lines += ["o Shiny", "usemtl shiny"]
    lines += ["f %d %d %d %d" % tuple(base + i for i in q) for q in quads]
    (OUT / "model.obj").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    write()
    print(f"wrote {OUT}")
