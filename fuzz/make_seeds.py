#!/usr/bin/python3
"""Writes the fuzzing seed corpus fuzz/seeds/{obj,ply,off}/ and the libFuzzer dictionaries
fuzz/{obj,ply,off}.dict: small valid files in every supported variant plus typical malformed ones.

Run: /usr/bin/python3 fuzz/make_seeds.py   (deterministic; the output is committed)
"""
import os
import shutil
import struct

HERE = os.path.dirname(os.path.abspath(__file__))

# A unit cube: 8 vertices, 6 quads (0-based).
CUBE_V = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)]
CUBE_F = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
TRI_V = [(0.0, 0.0, 0.0), (1.5, -0.25, 1e-3), (0.0, 2.0, -7.0)]


def obj_seeds():
    s = {}
    s["cube.obj"] = "".join("v %g %g %g\n" % v for v in CUBE_V) + "".join(
        "f " + " ".join(str(i + 1) for i in f) + "\n" for f in CUBE_F)
    s["tri_slashes.obj"] = (
        "# comment\nmtllib a.mtl\no tri\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n"
        "vn 0 0 1\ng g1\nusemtl m\ns off\nf 1/1/1 2/2/1 3/3/1\nf 1//1 2//1 3//1\nf 1/1 2/2 3/3\n")
    s["negative.obj"] = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\nv 0 0 1\nf -4 -1 2\n"
    s["crlf_colors.obj"] = "v 0 0 0 1 0 0\r\nv 1 0 0 0 1 0\r\nv 0 1 0 0 0 1\r\nf 1 2 3\r\n"
    s["continuation.obj"] = "v 0 0 0\nv 1 \\\n 0 0\nv 0 1 0\nf 1 2 \\\n3\n"
    s["polygon.obj"] = "".join("v %d %d 0\n" % (i, i * i) for i in range(7)) + "f 1 2 3 4 5 6 7\nl 1 2\np 3\n"
    s["pointcloud.obj"] = "v 1e3 -2.5e-3 +4\nv 0 0 0 0.5 0.5 0.5\n"
    s["forward_ref.obj"] = "f 1 2 3\nv 0 0 0\nv 1 0 0\nv 0 1 0\n"
    s["bad_index0.obj"] = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n"
    s["bad_range.obj"] = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n"
    s["bad_relative.obj"] = "v 0 0 0\nf -2 -1 1\n"
    s["bad_number.obj"] = "v 0 0 x\nv 1 0 0\n"
    s["bad_truncated.obj"] = "v 0 0 0\nv 1 0\n"
    s["bad_face_token.obj"] = "v 0 0 0\nf 1/a/1\nf 1/2/3/4\nf\n"
    s["bad_inf.obj"] = "v 1e999 0 0\nv inf 0 0\n"
    s["empty.obj"] = ""
    return s


def ply_header(fmt, elements):
    lines = ["ply", "format %s 1.0" % fmt, "comment seed"]
    for name, count, props in elements:
        lines.append("element %s %d" % (name, count))
        lines += ["property " + p for p in props]
    lines.append("end_header")
    return ("\n".join(lines) + "\n").encode()


STRUCT = {"char": "b", "uchar": "B", "short": "h", "ushort": "H", "int": "i", "uint": "I",
          "float": "f", "double": "d", "int8": "b", "uint8": "B", "int16": "h", "uint16": "H",
          "int32": "i", "uint32": "I", "float32": "f", "float64": "d"}


def ply_binary(endian, vtype, count_type, index_type, verts, faces, extra=True):
    """Binary PLY with x,y,z of `vtype`, an extra scalar and list on vertices, a `material`
    element between vertex and face, and faces with an extra uchar after the index list."""
    e = "<" if endian == "binary_little_endian" else ">"
    vprops = ["%s x" % vtype, "%s y" % vtype, "%s z" % vtype]
    if extra:
        vprops += ["uchar red", "list uchar float tex"]
    fprops = ["list %s %s vertex_indices" % (count_type, index_type)] + (["uchar flags"] if extra else [])
    elems = [("vertex", len(verts), vprops)]
    if extra:
        elems.append(("material", 2, ["float shine", "list int short ids"]))
    elems.append(("face", len(faces), fprops))
    out = bytearray(ply_header(endian, elems))
    for v in verts:
        out += struct.pack(e + STRUCT[vtype] * 3, *v)
        if extra:
            out += struct.pack(e + "BBff", 200, 2, 0.5, 0.25)
    if extra:
        for k in range(2):
            out += struct.pack(e + "fi", 1.0 + k, k) + struct.pack(e + "h" * k, *range(k))
    for f in faces:
        out += struct.pack(e + STRUCT[count_type], len(f)) + struct.pack(e + STRUCT[index_type] * len(f), *f)
        if extra:
            out += struct.pack(e + "B", 7)
    return bytes(out)


def ply_seeds():
    s = {}
    ascii_cube = ply_header("ascii", [("vertex", 8, ["float x", "float y", "float z", "uchar red"]),
                                      ("face", 6, ["list uchar int vertex_indices"])])
    ascii_cube += "".join("%g %g %g 255\n" % v for v in CUBE_V).encode()
    ascii_cube += "".join("4 %d %d %d %d\n" % f for f in CUBE_F).encode()
    s["cube_ascii.ply"] = ascii_cube
    s["cube_le.ply"] = ply_binary("binary_little_endian", "float", "uchar", "int", CUBE_V, CUBE_F)
    s["cube_be.ply"] = ply_binary("binary_big_endian", "double", "uint8", "uint32", CUBE_V, CUBE_F)
    s["tri_le_short.ply"] = ply_binary("binary_little_endian", "short", "ushort", "uint16",
                                       [(0, 0, 0), (1, 0, 0), (0, 1, 0)], [(0, 1, 2)], extra=False)
    s["tri_be_char.ply"] = ply_binary("binary_big_endian", "char", "int", "int",
                                      [(0, 0, 0), (1, 0, 0), (0, 1, 0)], [(0, 1, 2)])
    s["pointcloud_le.ply"] = ply_binary("binary_little_endian", "float64", "uchar", "int",
                                        TRI_V, [], extra=False)
    s["vertex_index.ply"] = ply_header("ascii", [("vertex", 3, ["double x", "double y", "double z"]),
                                                 ("face", 1, ["list int uint vertex_index"])]) + \
        b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
    good = s["cube_le.ply"]
    s["bad_truncated_le.ply"] = good[:-9]
    s["bad_huge_count.ply"] = ply_header("binary_little_endian", [("vertex", 10 ** 12, ["float x", "float y", "float z"])]) + b"\0" * 24
    s["bad_count_bytes.ply"] = ply_header("binary_big_endian", [("vertex", 1000, ["float x", "float y", "float z"])]) + b"\0" * 24
    s["bad_negative_count.ply"] = ply_header("ascii", [("vertex", -3, ["float x", "float y", "float z"])])
    s["bad_no_end.ply"] = b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n"
    s["bad_magic.ply"] = b"plx\nformat ascii 1.0\nend_header\n"
    s["bad_index.ply"] = ply_header("ascii", [("vertex", 3, ["float x", "float y", "float z"]),
                                              ("face", 1, ["list uchar int vertex_indices"])]) + \
        b"0 0 0\n1 0 0\n0 1 0\n3 0 1 5\n"
    s["bad_list_count.ply"] = ply_binary("binary_big_endian", "float", "int", "int",
                                         [(0, 0, 0)] * 3, [(0, 1, 2)], extra=False)[:-16] + struct.pack(">i", 2 ** 30) + b"\0" * 12
    s["bad_token.ply"] = ply_header("ascii", [("vertex", 1, ["float x", "float y", "float z"])]) + b"0 zero 0\n"
    return s


def off_seeds():
    s = {}
    s["cube.off"] = "OFF\n# cube\n8 6 12\n" + "".join("%g %g %g\n" % v for v in CUBE_V) + "".join(
        "4 %d %d %d %d\n" % f for f in CUBE_F)
    s["coff.off"] = "COFF\n3 1 0\n0 0 0 255 0 0 255\n1 0 0 0 255 0 255\n0 1 0 0 0 255 255\n3 0 1 2 1 0 0\n"
    s["noff_inline.off"] = "NOFF 3 1 0\n\n0 0 0 0 0 1\n1 0 0 0 0 1 # n\n0 1 0 0 0 1\n3 0 1 2\n"
    s["crlf.off"] = "OFF\r\n3 1 0\r\n0 0 0\r\n1 0 0\r\n0 1 0\r\n3 2 1 0\r\n"
    s["pointcloud.off"] = "OFF\n2 0\n1 2 3\n4 5 6\n"
    s["bad_magic.off"] = "OFX\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
    s["bad_counts.off"] = "OFF\n99999999999 1 0\n0 0 0\n"
    s["bad_negative.off"] = "OFF\n-3 1 0\n"
    s["bad_face_size.off"] = "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n1000000 0 1 2\n"
    s["bad_index.off"] = "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n"
    s["bad_truncated.off"] = "OFF\n3 1 0\n0 0 0\n1 0 0\n"
    s["bad_nan.off"] = "OFF\n1 0 0\nnan 0 0\n"
    return s


DICTS = {
    "obj": ["v", "f", "vt", "vn", "g", "o", "s", "usemtl", "mtllib", "#", "/", "//", "\\\n",
            "-1", "\r\n", "nan", "inf", "1e308"],
    "ply": ["ply\n", "format ascii 1.0\n", "format binary_little_endian 1.0\n",
            "format binary_big_endian 1.0\n", "element vertex ", "element face ", "property float x\n",
            "property double y\n", "property uchar z\n", "property list uchar int vertex_indices\n",
            "property list int uint vertex_index\n", "end_header\n", "comment", "obj_info",
            "char", "uint16", "int32", "float64", "\xff\xff\xff\x7f", "\x00\x00\x00\x80"],
    "off": ["OFF", "COFF", "NOFF", "STOFF", "4OFF", "BINARY", "#", "\n", "-1", "nan", "3 0 1 2\n"],
}


def dict_entry(tok):
    """A libFuzzer dictionary value: printable ASCII as is, everything else as \\xNN."""
    out = ""
    for ch in tok.encode("latin-1"):
        c = chr(ch)
        out += c if 32 <= ch < 127 and c not in '\\"' else "\\x%02x" % ch
    return '"%s"' % out


def main():
    for fmt, seeds in (("obj", obj_seeds()), ("ply", ply_seeds()), ("off", off_seeds())):
        d = os.path.join(HERE, "seeds", fmt)
        shutil.rmtree(d, ignore_errors=True)
        os.makedirs(d)
        for name, content in seeds.items():
            with open(os.path.join(d, name), "wb") as f:
                f.write(content if isinstance(content, bytes) else content.encode())
        with open(os.path.join(HERE, fmt + ".dict"), "w") as f:
            f.write("# libFuzzer dictionary for the %s reader (written by make_seeds.py)\n" % fmt.upper())
            for i, tok in enumerate(DICTS[fmt]):
                f.write("kw%d=%s\n" % (i, dict_entry(tok)))
        print("%s: %d seeds" % (fmt, len(seeds)))


if __name__ == "__main__":
    main()
