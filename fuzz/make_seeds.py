#!/usr/bin/env python3
"""Writes the checked-in seed corpora of fuzz/ (fuzz/corpus/<target>/) from
files the pipeline wrote on real data and on the rig. Run from the repository
root after the commands in fuzz/corpus/README.md; the seeds are small on
purpose (a fuzzer mutates small inputs faster)."""
import json, os, shutil, struct, sys, zlib

SEP = b"\n--s2r-part--\n"
src, out = sys.argv[1], "fuzz/corpus"


def put(target, name, data):
    d = os.path.join(out, target)
    os.makedirs(d, exist_ok=True)
    with open(os.path.join(d, name), "wb") as f:
        f.write(data)


def read(path):
    with open(path, "rb") as f:
        return f.read()


def payload(records, size):
    head = b"S2RB" + struct.pack("<II", 1, size) + b"\0" * 4 + struct.pack("<Q", len(records) // size)
    body = head + records
    return body + struct.pack("<I", zlib.crc32(body) & 0xFFFFFFFF)


def small_model(model_dir, facets):
    """The first `facets` facets of a model, their cameras, and the octree's
    first nodes (deeper children cut off), with textures left out."""
    doc = json.load(open(os.path.join(model_dir, "model.json")))
    fb = read(os.path.join(model_dir, "facets.bin"))[24:-4]
    fc = read(os.path.join(model_dir, "facet_cameras.bin"))[24:-4]
    ob = read(os.path.join(model_dir, "octree.bin"))[24:-4]
    recs, used = [], 0
    for i in range(facets):
        r = bytearray(fb[i * 40:(i + 1) * 40])
        first, count = struct.unpack_from("<II", r, 32)
        struct.pack_into("<II", r, 32, used, count)
        recs.append(bytes(r))
        used += count
    cams = b"".join(fc[(struct.unpack_from("<I", fb, i * 40 + 32)[0] + k) * 4:
                       (struct.unpack_from("<I", fb, i * 40 + 32)[0] + k + 1) * 4]
                    for i in range(facets) for k in range(struct.unpack_from("<I", fb, i * 40 + 36)[0]))
    nodes = []
    keep = 9
    for i in range(keep):
        n = bytearray(ob[i * 52:(i + 1) * 52])
        first, = struct.unpack_from("<I", n, 44)
        children = n[50]
        if first != 0xFFFFFFFF and first + children > keep:
            struct.pack_into("<I", n, 44, 0xFFFFFFFF)
            n[50] = 0
        nodes.append(bytes(n))
    for c in doc["cameras"]:
        c["texture"] = ""
    doc["payloads"]["facets"]["records"] = facets
    doc["payloads"]["facet_cameras"]["records"] = len(cams) // 4
    doc["payloads"]["octree"]["records"] = keep
    return SEP.join([json.dumps(doc, indent=1).encode(), payload(b"".join(recs), 40), payload(cams, 4),
                     payload(b"".join(nodes), 52)])


def ply_excerpt(path, row, col, rows, cols):
    """A window of an ASCII Stanford range scan: the rows x cols cells of its
    range grid from (row, col), the vertices they hold renumbered, the header's
    num_cols / num_rows and element counts made to match."""
    lines = read(path).split(b"\r\n")
    end = lines.index(b"end_header")
    head = lines[:end + 1]
    count = lambda name: int(next(l for l in head if l.startswith(b"element " + name)).split()[2])
    width = int(next(l for l in head if l.startswith(b"obj_info num_cols")).split()[2])
    nv = count(b"vertex")
    body = lines[end + 1:]
    cells, verts = [], []
    for r in range(row, row + rows):
        for c in range(col, col + cols):
            words = body[nv + r * width + c].split()
            if words[0] == b"0":
                cells.append(b"0")
            else:
                verts.append(body[int(words[1])])
                cells.append(b"1 %d" % (len(verts) - 1))
    out = []
    for l in head:
        if l.startswith(b"obj_info num_cols"):
            l = b"obj_info num_cols %d" % cols
        elif l.startswith(b"obj_info num_rows"):
            l = b"obj_info num_rows %d" % rows
        elif l.startswith(b"element vertex"):
            l = b"element vertex %d" % len(verts)
        elif l.startswith(b"element range_grid"):
            l = b"element range_grid %d" % len(cells)
        out.append(l)
    return b"\r\n".join(out + verts + cells) + b"\r\n"


def png_gray16(rows, interlace=0):
    """A 16-bit greyscale PNG of `rows` (lists of ints), every row filtered Sub
    (as the capture writes them), non-interlaced."""
    chunk = lambda kind, body: struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF)
    raw = b""
    for r in rows:
        px = struct.pack(">%dH" % len(r), *r)
        raw += b"\x01" + bytes((px[i] - (px[i - 2] if i >= 2 else 0)) & 0xFF for i in range(len(px)))
    head = struct.pack(">IIBBBBB", len(rows[0]), len(rows), 16, 0, 0, 0, interlace)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", head) + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b"")


def png_crop16(path, x0, y0, w, h):
    """A w x h window of a non-interlaced 16-bit greyscale PNG (any filters)."""
    data = read(path)
    pos, idat, width = 8, b"", 0
    while pos < len(data):
        n, = struct.unpack_from(">I", data, pos)
        kind = data[pos + 4:pos + 8]
        if kind == b"IHDR":
            width, = struct.unpack_from(">I", data, pos + 8)
        if kind == b"IDAT":
            idat += data[pos + 8:pos + 8 + n]
        pos += 12 + n
    raw, stride, prev, rows = zlib.decompress(idat), 2 * width, None, []
    for y in range(y0 + h):
        f, line = raw[y * (stride + 1)], bytearray(raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)])
        up = prev or bytearray(stride)
        for i in range(stride):
            a, b, c = (line[i - 2] if i >= 2 else 0), up[i], (up[i - 2] if i >= 2 else 0)
            pred = (0, a, b, (a + b) // 2, min((a, b, c), key=lambda v: (abs(a + b - c - v), (a, b, c).index(v))))[f]
            line[i] = (line[i] + pred) & 0xFF
        prev = line
        if y >= y0:
            rows.append([struct.unpack_from(">H", line, 2 * x)[0] for x in range(x0, x0 + w)])
    return rows


data = os.environ.get("S2R_DATA", "../shared/data")
# Sessions: imports of the real data and a capture through the drivers.
for name in ("bear", "bunny", "dino"):
    put("session", name, read(f"{src}/{name}/session.json"))
put("session", "capture_with_journal",
    read("out/demo/capture/session.json") + SEP + read("out/demo/capture/session.journal"))
# Calibrations: the bear's marker calibration, chessboard intrinsics.
put("calibration", "bear_markers", read(f"{src}/bear-cal.json"))
put("calibration", "chessboard", read(f"{src}/chess-cal.json"))
# Poses: the Stanford bunny registered.
put("poses", "bunny", read("out/demo/register/poses.json"))
# Stanford .conf files: the real one and the one registration writes back.
put("stanford_conf", "bun", read(f"{data}/stanford_bunny/bun.conf"))
put("stanford_conf", "registered", read("out/demo/register/bun.conf"))
# PLY: a window of a real scan's range grid; the rig model's patch mesh is binary.
put("ply", "bun000_excerpt", ply_excerpt(f"{data}/stanford_bunny/bun000.ply", 24, 124, 8, 10))
tet = struct.pack("<12f", 0, 0, 0, 0.01, 0, 0, 0, 0.01, 0, 0, 0, 0.01) + b"".join(
    struct.pack("<B3i", 3, *f) for f in ((0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)))
put("ply", "tetrahedron_binary", b"ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty float x\n"
    b"property float y\nproperty float z\nelement face 4\nproperty list uchar int vertex_indices\nend_header\n" + tet)
# Depth PNGs (16-bit greyscale): a window of the real bear's depth frame, and
# a frame with no valid sample.
put("depth_png", "bear_window", png_gray16(png_crop16(f"{data}/realsense_d435_bear/data1/depth_5.png", 300, 220, 12, 9)))
put("depth_png", "all_zero", png_gray16([[0] * 5] * 3))
# Models: a few facets of the rig's bunny.
put("model", "rig_bunny_small", small_model("out/demo/model", 12))
# Serial: what a GRBL board says during a move (banner, ok, status, faults).
put("serial", "move", b"\x05Grbl 1.1h ['$' for help]\r\nok\r\n<Run|MPos:12.500,0.000,0.000|FS:500,0>\r\n"
    b"<Idle|MPos:15.000,0.000,0.000|FS:0,0>\r\nok\r\n")
put("serial", "faults", b"\x41~#ok\r\nerror:9\r\n[MSG:Caution: Unlocked]\nALARM:2\r<Alarm|MPos:1.0,2.0,3.0>\n"
    b"\xff\xfe garbage\r\n")
# V4L2: the checked-in recordings are used as they are (fixtures/v4l2).
