#!/usr/bin/env python3
"""Writes the seed corpora fuzz/corpus/<parser>/ from the real files in data/ plus hand-made edge
cases (standard library only). The seeds are committed; run this again after changing it:
    python3 fuzz/make_seeds.py
Large real files are cut down: PLUS sequences keep their real header and fields with fewer,
smaller frames; meshes keep their first KB (a truncated file is itself a good seed) and a
small complete mesh is made by hand in each format."""
import gzip
import json
import os
import re
import shutil
import struct
import zlib

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.path.join(ROOT, "data")
OUT = os.path.join(ROOT, "fuzz", "corpus")


def put(parser, name, content):
    d = os.path.join(OUT, parser)
    os.makedirs(d, exist_ok=True)
    if isinstance(content, str):
        content = content.encode()
    with open(os.path.join(d, name), "wb") as f:
        f.write(content)


def read(*path):
    with open(os.path.join(DATA, *path), "rb") as f:
        return f.read()


def npy(shape, dtype="<f8", data=None, version=1, fortran=False):
    header = "{'descr': '%s', 'fortran_order': %s, 'shape': (%s), }" % (
        dtype, "True" if fortran else "False",
        "".join("%d, " % s for s in shape) if len(shape) != 1 else "%d," % shape[0])
    if len(shape) > 1:
        header = header.replace(", ), }", "), }")
    magic = b"\x93NUMPY" + bytes([version, 0])
    size_len = 2 if version == 1 else 4
    total = len(magic) + size_len + len(header) + 1
    header += " " * ((64 - total % 64) % 64) + "\n"
    fmt = "<H" if version == 1 else "<I"
    count = 1
    for s in shape:
        count *= s
    if data is None:
        item = int(dtype[2:])
        data = bytes((i * 7) % 256 for i in range(count * item))
    return magic + struct.pack(fmt, len(header)) + header.encode("latin1") + data


IDENTITY = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]
POSE = [0, 0, -1, 10, 0, 1, 0, -120, 1, 0, 0, 35, 0, 0, 0, 1]


def f64(values):
    return struct.pack("<%dd" % len(values), *values)


def crc64(data):
    """OpenIGTLink's CRC-64 (ECMA-182 polynomial, not reflected, initial value 0)."""
    crc = 0
    for byte in data:
        crc ^= byte << 56
        for _ in range(8):
            crc = ((crc << 1) ^ 0x42F0E1EBA9EA3693) if crc & (1 << 63) else crc << 1
            crc &= (1 << 64) - 1
    return crc


def igtl(kind, device, content, version=1, metadata=()):
    """An OpenIGTLink message: the 58-byte header, [extended header], content, [metadata]."""
    body = content
    if version == 2:
        keys = b"".join(struct.pack(">HHI", len(k), 3, len(v)) for k, v in metadata)
        values = b"".join(k + v for k, v in metadata)
        meta_header = struct.pack(">H", len(metadata)) + keys
        body = struct.pack(">HHII", 12, len(meta_header), len(values), 7) + content + meta_header + values
    return (struct.pack(">H12s20sQQQ", version, kind, device, 0, len(body), crc64(body)) + body)


def igtl_seeds():
    """OpenIGTLink streams as `sonoslice live` receives them (fuzz_igtl)."""
    w, h = 6, 4
    matrix = struct.pack(">12f", 0.3, 0, 0, 0, 0.3, 0, 0, 0, 1, 1.5, 2.5, 0)
    image = struct.pack(">HBBBBHHH", 1, 1, 3, 2, 2, w, h, 1) + matrix + struct.pack(">6H", 0, 0, 0, w, h, 1)
    image += bytes(range(w * h))
    transform = struct.pack(">12f", 1, 0, 0, 0, 1, 0, 0, 0, 1, 10, 20, 30)
    command = b'<Command Name="StopVolumeReconstruction" OutputVolDeviceName="Volume" />'
    string = struct.pack(">HH", 3, len(command)) + command
    status = struct.pack(">Hq20s", 1, 0, b"") + b"300 frames\0"
    cmd_v2 = struct.pack(">I128sHI", 3, b"StopVolumeReconstruction", 3, len(command)) + command
    put("igtl", "image-v1.bin", igtl(b"IMAGE", b"Image_Reference", image))
    put("igtl", "image-v2-metadata.bin", igtl(b"IMAGE", b"Image_Reference", image, 2, [(b"Key", b"value")]))
    put("igtl", "transform.bin", igtl(b"TRANSFORM", b"ProbeToReference", transform))
    put("igtl", "string-command.bin", igtl(b"STRING", b"CMD_1", string))
    put("igtl", "status.bin", igtl(b"STATUS", b"", status))
    put("igtl", "command-v2.bin", igtl(b"COMMAND", b"command", cmd_v2, 2, [(b"Name", b"x")]))
    put("igtl", "stream.bin", igtl(b"IMAGE", b"a", image) + igtl(b"STRING", b"CMD_2", string) +
        igtl(b"GET_STATUS", b"", b""))
    put("igtl", "image-3d-rgb.bin", igtl(b"IMAGE", b"x", image[:2] + b"\x03" + image[3:10] + b"\x00\x02" +
                                         image[12:] + bytes(2 * w * h) * 3))


# DICOM Part 10 (PS3.10): a 128-byte preamble, "DICM", the meta group (always explicit VR little
# endian), then the data set in the transfer syntax the meta group names.
EXPLICIT, IMPLICIT, RLE = "1.2.840.10008.1.2.1", "1.2.840.10008.1.2", "1.2.840.10008.1.2.5"
LONG_VRS = {"OB", "OD", "OF", "OL", "OV", "OW", "SQ", "SV", "UC", "UN", "UR", "UT", "UV"}


def dicom_element(group, element, vr, value, explicit=True, undefined=False):
    if isinstance(value, str):
        value = value.encode()
        value += (b"\0" if vr == "UI" else b" ") * (len(value) % 2)
    length = 0xFFFFFFFF if undefined else len(value)
    tag = struct.pack("<HH", group, element)
    if not explicit or group == 0xFFFE:
        return tag + struct.pack("<I", length) + value
    if vr in LONG_VRS:
        return tag + vr.encode() + b"\0\0" + struct.pack("<I", length) + value
    return tag + vr.encode() + struct.pack("<H", length) + value


def dicom_item(content, undefined=False):
    if undefined:
        return dicom_element(0xFFFE, 0xE000, "", content, undefined=True) + struct.pack("<HHI", 0xFFFE, 0xE00D, 0)
    return dicom_element(0xFFFE, 0xE000, "", content)


def rle_frame(pixels, samples):
    """One RLE Lossless frame (PS3.5 G): one segment per byte plane, literal runs of <= 128."""
    planes = [pixels[s::samples] for s in range(samples)]
    segments = []
    for plane in planes:
        seg = b"".join(bytes([len(plane[i:i + 128]) - 1]) + plane[i:i + 128] for i in range(0, len(plane), 128))
        segments.append(seg + b"\0" * (len(seg) % 2))
    offsets, at = [], 64
    for seg in segments:
        offsets.append(at)
        at += len(seg)
    return struct.pack("<16I", len(segments), *(offsets + [0] * (15 - len(offsets)))) + b"".join(segments)


def dicom_clip(w, h, frames, samples=1, bits=8, syntax=EXPLICIT, regions=True, big=False):
    """A multi-frame ultrasound clip in `syntax`, with a regions sequence holding the deltas."""
    explicit = syntax != IMPLICIT
    e = lambda g, el, vr, v, **kw: dicom_element(g, el, vr, v, explicit=explicit, **kw)
    us = lambda v: struct.pack("<H", v)
    meta_body = (dicom_element(2, 1, "OB", b"\0\1") +
                 dicom_element(2, 2, "UI", "1.2.840.10008.5.1.4.1.1.3.1") +
                 dicom_element(2, 3, "UI", "1.2.826.0.1.3680043.2.1125.9.%d.%d" % (w, frames)) +
                 dicom_element(2, 0x10, "UI", syntax) + dicom_element(2, 0x12, "UI", "1.2.826.0.1.3680043.2.1125"))
    meta = dicom_element(2, 0, "UL", struct.pack("<I", len(meta_body))) + meta_body
    body = (e(8, 0x16, "UI", "1.2.840.10008.5.1.4.1.1.3.1") + e(8, 0x18, "UI", "1.2.826.0.1.3680043.2.1125.9.1") +
            e(8, 0x60, "CS", "US"))
    if regions:
        region = (e(0x18, 0x6012, "US", us(1)) + e(0x18, 0x6014, "US", us(1)) + e(0x18, 0x6024, "US", us(3)) +
                  e(0x18, 0x6026, "US", us(3)) + e(0x18, 0x602C, "FD", struct.pack("<d", 0.02)) +
                  e(0x18, 0x602E, "FD", struct.pack("<d", 0.03)))
        body += e(0x18, 0x6011, "SQ", dicom_item(region, undefined=big), undefined=big) + \
            (struct.pack("<HHI", 0xFFFE, 0xE0DD, 0) if big else b"")
    body += e(0x28, 2, "US", us(samples)) + e(0x28, 4, "CS", "MONOCHROME2" if samples == 1 else "RGB")
    if samples == 3:
        body += e(0x28, 6, "US", us(0))
    body += (e(0x28, 8, "IS", str(frames)) + e(0x28, 0x10, "US", us(h)) + e(0x28, 0x11, "US", us(w)) +
             e(0x28, 0x30, "DS", "0.3\\0.2") + e(0x28, 0x100, "US", us(bits)) + e(0x28, 0x101, "US", us(bits)) +
             e(0x28, 0x102, "US", us(bits - 1)) + e(0x28, 0x103, "US", us(0)))
    size = w * h * samples * bits // 8
    frame = [bytes((x * 5 + y * 3 + k * 11 + i) % 256 for i in range(size)) for k in range(frames)
             for x, y in [(k, k)]]
    if syntax == RLE:
        items = dicom_item(b"") + b"".join(dicom_item(rle_frame(f, samples)) for f in frame)
        body += e(0x7FE0, 0x10, "OB", items, undefined=True) + struct.pack("<HHI", 0xFFFE, 0xE0DD, 0)
    else:
        pixels = b"".join(frame)
        body += e(0x7FE0, 0x10, "OB" if bits == 8 else "OW", pixels + b"\0" * (len(pixels) % 2))
    return b"\0" * 128 + b"DICM" + meta + body


def dicom_seeds():
    put("dicom", "clip-u8-explicit.dcm", dicom_clip(6, 4, 3))
    put("dicom", "clip-u8-implicit.dcm", dicom_clip(6, 4, 2, syntax=IMPLICIT))
    put("dicom", "clip-u8-undefined-regions.dcm", dicom_clip(5, 4, 2, big=True))
    put("dicom", "clip-rgb-explicit.dcm", dicom_clip(4, 3, 2, samples=3))
    put("dicom", "clip-u16-noregions.dcm", dicom_clip(4, 3, 2, bits=16, regions=False))
    put("dicom", "clip-u8-rle.dcm", dicom_clip(6, 4, 2, syntax=RLE))
    put("dicom", "clip-rgb-rle.dcm", dicom_clip(4, 3, 2, samples=3, syntax=RLE))
    put("dicom", "single-frame.dcm", dicom_clip(6, 4, 1, regions=False))
    put("dicom", "truncated.dcm", dicom_clip(6, 4, 3)[:-9])


# PNG (ISO/IEC 15948): the signature, then chunks (length, type, data, CRC-32).
def png_chunk(kind, data):
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def png(w, h, colour, depth, rows, extra=b"", palette=None):
    """A PNG of `rows` (packed scanlines, filter 0 each) in colour type `colour`, bit depth `depth`."""
    out = b"\x89PNG\r\n\x1a\n" + png_chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, depth, colour, 0, 0, 0))
    out += extra + (png_chunk(b"PLTE", palette) if palette else b"")
    return out + png_chunk(b"IDAT", zlib.compress(b"".join(b"\0" + r for r in rows))) + png_chunk(b"IEND", b"")


def png_seeds():
    grey = [bytes((x * 40 + y * 7) % 256 for x in range(6)) for y in range(4)]
    put("png", "grey8.png", png(6, 4, 0, 8, grey))
    put("png", "grey8-scal.png", png(6, 4, 0, 8, grey, extra=png_chunk(b"sCAL", b"\x02" + b"0.0003\x000.0002")))
    put("png", "grey16.png", png(3, 2, 0, 16, [struct.pack(">3H", 1, 300, 65535), struct.pack(">3H", 7, 0, 9)]))
    put("png", "rgb8.png", png(2, 2, 2, 8, [bytes(range(6)), bytes(range(6, 12))]))
    put("png", "rgba8.png", png(2, 2, 6, 8, [bytes(range(8)), bytes(range(8, 16))]))
    put("png", "grey-alpha8.png", png(2, 2, 4, 8, [bytes(range(4)), bytes(range(4, 8))]))
    put("png", "palette4.png", png(4, 2, 3, 4, [b"\x01\x23", b"\x20\x10"], palette=bytes(range(12))))
    put("png", "grey1.png", png(9, 2, 0, 1, [b"\xa5\x80", b"\x5a\x00"]))
    put("png", "truncated.png", png(6, 4, 0, 8, grey)[:-20])
    put("png", "claims-30000x30000.png", png(30000, 30000, 0, 8, grey))


def main():
    if os.path.isdir(OUT):
        shutil.rmtree(OUT)

    # ---- pose files ----------------------------------------------------------------------
    line16 = " ".join(str(v) for v in POSE)
    put("pose_text", "docs-16.txt", "# the worked example of docs/conventions.md §2\n" + line16 + "\n")
    put("pose_text", "docs-12.csv", "0,0,-1,10, 0,1,0,-120, 1,0,0,35\n0,0,-1,11, 0,1,0,-120, 1,0,0,35\n")
    put("pose_text", "tabs-semicolons.txt", "1\t0\t0\t0;0 1 0 0;0 0 1 0; 0 0 0 1 # comment\n\n"
        "0.9999999999999999 1e-17 0 -0 0 1 0 5e+2 0 0 1 -1E3 0 0 0 1\r\n")
    put("pose_text", "bad-values.txt", "nan 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n"
        "inf 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n1e999 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n"
        "0x1p3 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n1 2 3\n")
    put("pose_text", "degenerate.txt", "0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0\n"
        "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 2\n")
    put("pose_text", "empty.txt", "")
    put("pose_text", "comments-only.csv", "# x,y\n#\n")
    put("pose_json", "docs.json", json.dumps({"poses": [POSE]}))
    put("pose_json", "nested.json", json.dumps({"poses": [[POSE[0:4], POSE[4:8], POSE[8:12], POSE[12:16]],
                                                          IDENTITY]}))
    put("pose_json", "bad.json", '{"poses": [[1, 2, "3"], null, [1e400]], "extra": 1}')
    put("pose_json", "empty-list.json", '{"poses": []}')
    put("pose_json", "not-object.json", "[[1,0,0,0]]")
    put("pose_npy", "n44-f8.npy", npy((2, 4, 4), "<f8", f64(POSE + IDENTITY)))
    put("pose_npy", "strip-4x8-f4.npy", npy((4, 8), "<f4", struct.pack(
        "<32f", *[v for r in range(4) for v in (POSE[4 * r:4 * r + 4] + IDENTITY[4 * r:4 * r + 4])])))
    put("pose_npy", "n44-f8-bigendian.npy", npy((1, 4, 4), ">f8", struct.pack(">16d", *POSE)))
    put("pose_npy", "n44-fortran.npy", npy((1, 4, 4), "<f8", f64(POSE), fortran=True))
    put("pose_npy", "n44-complex.npy", npy((1, 4, 4), "<c16", f64([v for p in POSE for v in (p, 0)])))
    put("pose_npy", "n44-int.npy", npy((1, 4, 4), "<i8", struct.pack("<16q", *POSE)))

    # ---- .npy arrays --------------------------------------------------------------------
    for dt in ["|u1", "|i1", "<u2", "<i2", "<i4", "<u4", "<f4", "<f8", ">i2", ">f4", "<i8", "|b1", "<f2"]:
        put("npy", "2x3x4-%s.npy" % dt.replace("<", "le-").replace(">", "be-").replace("|", ""),
            npy((2, 3, 4), dt))
    put("npy", "v2-fortran.npy", npy((3, 2, 2), "<f4", version=2, fortran=True))
    put("npy", "v3.npy", npy((2, 2, 2), "<i2", version=3))
    put("npy", "scalar.npy", npy((), "<f8", f64([1.0])))
    put("npy", "zero-size.npy", npy((0, 3, 4), "<f4", b""))
    put("npy", "truncated.npy", npy((4, 4, 4), "<f4")[:-7])
    put("npy", "huge-shape.npy", npy((4294967296, 4294967296, 1), "<f4", b"\0" * 16))
    put("npy", "negative-shape.npy", npy((2, 3, 4), "<f4").replace(b"(2, 3, 4)", b"(2,-3, 4)"))

    # ---- probe JSON and fan-slicer configurations ------------------------------------------
    for name in sorted(os.listdir(os.path.join(DATA, "fanslicer"))):
        if name.endswith(".json"):
            put("probe_json", name.replace(" ", "_"), read("fanslicer", name))
            put("fanslicer_config", name.replace(" ", "_"), read("fanslicer", name))
    native = {"type": "curvilinear", "radius_mm": 46.93, "depth_mm": 64.96, "sector_deg": 36,
              "face_y_mm": 2.1, "image": {"width": 334, "height": 272, "spacing_mm": [0.247, 0.247],
                                          "origin_mm": [-41.25, 0.0]}}
    put("probe_json", "native-curvilinear.json", json.dumps(native))
    put("probe_json", "native-linear.json", json.dumps(
        {"type": "linear", "width_mm": 40, "depth_mm": 60,
         "image": {"width": 64, "height": 48, "spacing_mm": [0.5, 0.5]}}))
    put("probe_json", "native-huge.json", json.dumps(
        {"type": "linear", "image": {"width": 2147483647, "height": 2147483647,
                                     "spacing_mm": [1e-300, 1e308]}}))
    put("probe_json", "native-bad-types.json", '{"type": 3, "radius_mm": "a", "sector_deg": -1e999,'
        ' "image": {"width": 1.5, "height": -2, "spacing_mm": [0], "origin_mm": null}}')
    put("probe_json", "fanslicer-linear.json", json.dumps(
        {"simulation": {"transducer": "linear", "image_dimensions": [400, 500],
                        "pixel_size": [0.1235, 0.1235]}}))
    put("probe_json", "fanslicer-zero.json", json.dumps(
        {"simulation": {"fan_geometry": [0, 0, 0, 0, 0, 0], "image_dimensions": [0, 1e10],
                        "pixel_size": [0, -1]}}))
    put("probe_json", "truncated.json", json.dumps(native)[:57])

    # ---- tissue tables and pose sampler settings ------------------------------------------
    liver = {"name": "liver", "label": 3, "impedance_mrayl": 1.65, "attenuation_db_cm_mhz": 0.5,
             "scatter_mean": 0.025, "scatter_density": 10}
    put("tissue_json", "table.json", json.dumps({"tissues": [
        {"name": "air", "label": 0, "impedance_mrayl": 0.0004, "attenuation_db_cm_mhz": 12,
         "scatter_mean": 0},
        {"name": "fat", "label": 1, "impedance_mrayl": 1.38, "attenuation_db_cm_mhz": 0.48,
         "scatter_mean": 0.012, "colour": [255, 230, 150]}, liver], "notes": "a user's words"}, indent=2))
    put("tissue_json", "bad-values.json", json.dumps({"tissues": [
        dict(liver, label=65536), dict(liver, impedance_mrayl=-1), dict(liver, name=7),
        dict(liver, scatter_density=1e308)]}).replace("1e+308", "1e400"))
    put("tissue_json", "duplicate-labels.json", json.dumps({"tissues": [liver, dict(liver, name="b")]}))
    put("tissue_json", "missing-key.json", '{"tissues": [{"name": "x", "label": 1}], "bogus": 1}')
    put("tissue_json", "not-a-table.json", '[{"tissues": null}]')
    put("tissue_json", "deep.json", '{"tissues": [], "notes": ' + "[" * 80 + "]" * 80 + "}")
    put("tissue_json", "truncated.json", json.dumps({"tissues": [liver]})[:40])
    put("sampler_json", "skin.json", json.dumps(
        {"type": "skin", "threshold_hu": -500, "rotation_deg": [0, 360], "tilt_deg": [-15, 15],
         "heel_toe_deg": [-10, 10], "depth_mm": [0, 5], "max_tries": 1000,
         "reject": {"min_inside": 0.9, "min_body": 0.6, "no_gas": True, "gas_hu": -400,
                    "gas_depth_mm": 5}}))
    put("sampler_json", "region-label.json", json.dumps(
        {"type": "region", "label": 3, "cone_deg": 30, "direction": [0, 0, 1], "anchor": "centre",
         "reject": {"label": 3, "min_label": 0.5}}))
    put("sampler_json", "region-intensity.json", json.dumps(
        {"type": "region", "intensity": [-100, 100], "rotation_deg": 45}))
    put("sampler_json", "mesh.json", json.dumps({"type": "mesh", "tilt_deg": [-5, 5]}))
    put("sampler_json", "sweep-from-skin.json", json.dumps(
        {"type": "sweep", "motion": "fan", "step": 1.5, "frames": 8, "jitter_mm": 0.2,
         "jitter_deg": 0.1, "from": {"type": "skin", "reject": {"min_body": 0.5}}}))
    put("sampler_json", "sweep-start.json", json.dumps(
        {"type": "sweep", "motion": "rotational", "start": [POSE[0:4], POSE[4:8], POSE[8:12],
                                                            POSE[12:16]]}))
    put("sampler_json", "bad-values.json", '{"type": "skin", "tilt_deg": [5, -5], "max_tries": 1e400,'
        ' "depth_mm": "a", "reject": {"min_inside": 2, "label": 2147483648}}')
    put("sampler_json", "sweep-of-sweep.json", json.dumps(
        {"type": "sweep", "from": {"type": "sweep", "from": {"type": "skin"}}}))
    put("sampler_json", "deep.json", '{"type": "sweep", "from": ' * 70 + '{"type": "skin"}' + "}" * 70)
    put("fanslicer_config", "sidecar.json", json.dumps({"spacing": [0.5, 0.5, 2], "origin": [1, 2, 3],
                                                        "direction": [1, 0, 0, 0, 1, 0, 0, 0, 1]}))
    put("fanslicer_config", "sidecar-bad.json", '{"spacing": [0, -1, 1e999], "origin": [1, 2], "x": 1}')
    put("fanslicer_config", "npy-config-mismatch.json", json.dumps(
        {"voxel size": [1, 1, 1], "bounding box": [[0, 0, 0], [1e300, -5, 2]], "planar resolution": 1}))
    put("fanslicer_config", "beam-geometry.json", json.dumps(
        {"r0_mm": 0.3, "dr_mm": 0.3, "azimuth0_deg": -18.7, "dazimuth_deg": 0.45,
         "elevation0_deg": -9.2, "delevation_deg": 0.88, "apex_offset_mm": 0}))
    put("fanslicer_config", "models-mismatch.json", json.dumps(
        {"models": {"files": ["liver", "../../etc/passwd", ""]},
         "simulation": {"simulation_models": [1, 1, 1, 1], "colors": [[255, 0], [256, -1, 3]]}}))

    # ---- NIfTI ----------------------------------------------------------------------------
    def nifti(dims, datatype, bitpix, data, pixdim=(1, 1, 1), slope=0.0, inter=0.0,
              qform=1, sform=0, vox_offset=352.0, extension=b"\0\0\0\0"):
        h = bytearray(348)
        struct.pack_into("<i", h, 0, 348)
        struct.pack_into("<8h", h, 40, len(dims), *(list(dims) + [1] * (7 - len(dims))))
        struct.pack_into("<hh", h, 70, datatype, bitpix)
        struct.pack_into("<8f", h, 76, 1.0, *(list(pixdim) + [1.0] * (7 - len(pixdim))))
        struct.pack_into("<f", h, 108, vox_offset)
        struct.pack_into("<ff", h, 112, slope, inter)
        struct.pack_into("<hh", h, 252, qform, sform)
        struct.pack_into("<6f", h, 256, 0, 0, 0, -10.0, 20.0, 5.0)  # quatern_b..d, qoffset_x..z
        struct.pack_into("<12f", h, 280, 0.5, 0, 0, 1, 0, 0.5, 0, 2, 0, 0, 2, 3)  # srow_x..z
        h[344:348] = b"n+1\0"
        return bytes(h) + extension + data

    vox = bytes((i * 13) % 256 for i in range(4 * 3 * 2 * 2))
    put("nifti", "int16-4x3x2.nii", nifti((4, 3, 2), 4, 16, vox))
    put("nifti", "int16-4x3x2.nii.gz", gzip.compress(nifti((4, 3, 2), 4, 16, vox), mtime=0))
    put("nifti", "uint8-sform.nii", nifti((4, 3, 2), 2, 8, vox[:24], qform=0, sform=1))
    put("nifti", "float32-slope.nii", nifti((2, 3, 2), 16, 32, vox[:48], slope=2.0, inter=-5.0))
    put("nifti", "nan-slope.nii", nifti((2, 3, 2), 16, 32, vox[:48], slope=float("nan"), inter=1.0))
    put("nifti", "pixdim-zero.nii", nifti((4, 3, 2), 4, 16, vox, pixdim=(0, 1, float("nan"))))
    put("nifti", "4d.nii", nifti((2, 2, 2, 3), 2, 8, vox[:24]))
    put("nifti", "rgb.nii", nifti((2, 2, 2), 128, 24, vox[:24]))
    put("nifti", "truncated.nii", nifti((4, 3, 2), 4, 16, vox)[:-5])
    put("nifti", "huge-dims.nii", nifti((32767, 32767, 32767), 64, 64, vox))
    put("nifti", "extension.nii", nifti((2, 2, 2), 2, 8, vox[:8], vox_offset=368.0,
                                        extension=b"\1\0\0\0" + struct.pack("<ii", 16, 4) + b"abcdefgh"))
    put("nifti", "bad-vox-offset.nii", nifti((2, 2, 2), 2, 8, vox[:8], vox_offset=-1e30))
    put("nifti", "truncated-gzip.nii.gz", gzip.compress(nifti((4, 3, 2), 4, 16, vox), mtime=0)[:-9])

    # ---- PLUS sequences ---------------------------------------------------------------------
    def small_mha(src, frames, w, h, compress):
        text = read("plus", src)
        head = text[:text.index(b"ElementDataFile")].decode("latin1")
        out = []
        for line in head.splitlines():
            m = re.match(r"Seq_Frame(\d+)_", line)
            if m and int(m.group(1)) >= frames:
                continue
            if line.startswith("DimSize"):
                line = "DimSize = %d %d %d" % (w, h, frames)
            out.append(line)
        pixels = bytes((i * 31 + i // w) % 256 for i in range(w * h * frames))
        if compress:
            data = zlib.compress(pixels)
            out = [("CompressedDataSize = %d" % len(data)) if l.startswith("CompressedDataSize") else l
                   for l in out]
        else:
            data = pixels
            out = [l for l in out if not l.startswith("CompressedDataSize")]
            out = [("CompressedData = False") if l.startswith("CompressedData") else l for l in out]
        return ("\n".join(out) + "\nElementDataFile = LOCAL\n").encode() + data

    put("plus_mha", "nwire-3frames-raw.igs.mha", small_mha("NwirePhantomFreehand.igs.mha", 3, 8, 6, False))
    put("plus_mha", "nwire-3frames-zlib.igs.mha", small_mha("NwirePhantomFreehand.igs.mha", 3, 8, 6, True))
    put("plus_mha", "bone-2frames-raw.igs.mha", small_mha("BoneUltrasound_L14.igs.mha", 2, 5, 4, False))
    mha = read("plus", "NwirePhantomFreehand.igs.mha")
    put("plus_mha", "nwire-header-1k.igs.mha", mha[:mha.index(b"ElementDataFile") + 1024])
    put("plus_mha", "reconstructed-volume-head.mha", read("plus", "NwirePhantomFreehandReconstructed.mha")[:2048])

    def small_nrrd(frames, w, h, encoding):
        text = read("plus", "NwirePhantomFreehand.igs.nrrd")
        end = text.index(b"\n\n")
        out = []
        for line in text[:end].decode("latin1").splitlines():
            m = re.match(r"Seq_Frame(\d+)_", line)
            if m and int(m.group(1)) >= frames:
                continue
            if line.startswith("sizes:"):
                line = "sizes: %d %d %d" % (w, h, frames)
            if line.startswith("encoding:"):
                line = "encoding: " + encoding
            out.append(line)
        pixels = bytes((i * 31 + i // w) % 256 for i in range(w * h * frames))
        data = gzip.compress(pixels, mtime=0) if encoding == "gz" else pixels
        return ("\n".join(out) + "\n\n").encode() + data

    put("plus_nrrd", "nwire-3frames-raw.igs.nrrd", small_nrrd(3, 8, 6, "raw"))
    put("plus_nrrd", "nwire-3frames-gz.igs.nrrd", small_nrrd(3, 8, 6, "gz"))
    put("plus_nrrd", "nwire-1frame-raw.igs.nrrd", small_nrrd(1, 4, 3, "raw"))
    nrrd = read("plus", "NwirePhantomFreehand.igs.nrrd")
    put("plus_nrrd", "nwire-header-1k.igs.nrrd", nrrd[:nrrd.index(b"\n\n") + 1026])

    # ---- PLUS configuration XML -------------------------------------------------------------
    for name in sorted(os.listdir(os.path.join(DATA, "plus"))):
        if name.endswith(".xml"):
            put("plus_xml", name, read("plus", name))
    put("plus_xml", "edge-values.xml", """<PlusConfiguration version="2.0">
  <CoordinateDefinitions>
    <Transform From="Image" To="Probe" Matrix="0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0"/>
    <Transform From="Probe" To="Image" Matrix="1 0 0 nan 0 1 0 0 0 0 1 0 0 0 0 1"/>
    <Transform From="Reference" To="Tracker" Matrix="1 2 3"/>
  </CoordinateDefinitions>
  <VolumeReconstruction ImageCoordinateFrame="Image" ReferenceCoordinateFrame="Reference"
    OutputSpacing="0 -1 1e999" OutputOrigin="0 0 0" OutputExtent="0 2147483647 0 -5 0 1"
    ClipRectangleOrigin="-1 -1" ClipRectangleSize="0 0" FanAnglesDeg="-90 90" FanOriginPixel="0 0"
    FanRadiusStartPixel="10" FanRadiusStopPixel="5" SkipInterval="0" Interpolation="linear"
    CompoundingMode="MAXIMUM" FillHoles="ON" NumberOfThreads="-3" Typo="1">
    <HoleFilling><HoleFillingElement Type="GAUSSIAN" Size="3" Stdev="0" MinRatio="2"/></HoleFilling>
  </VolumeReconstruction>
</PlusConfiguration>
""")
    put("plus_xml", "not-plus.xml", "<?xml version='1.0'?><a><b c='&amp;'/></a>")
    put("plus_xml", "truncated.xml", read("plus", "BoneUltrasound_L14_config.xml")[:400])

    # ---- meshes -----------------------------------------------------------------------------
    pts = [(0, 0, 0), (10, 0, 0), (0, 10, 0), (0, 0, 10)]
    tris = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]
    put("mesh_vtk", "tetra-ascii.vtk", "# vtk DataFile Version 3.0\ntetra\nASCII\nDATASET POLYDATA\n"
        "POINTS 4 float\n" + "\n".join("%g %g %g" % p for p in pts) + "\n"
        "POLYGONS 4 16\n" + "\n".join("3 %d %d %d" % t for t in tris) + "\n")
    put("mesh_vtk", "tetra-binary.vtk", b"# vtk DataFile Version 3.0\ntetra\nBINARY\nDATASET POLYDATA\n"
        b"POINTS 4 float\n" + struct.pack(">12f", *[c for p in pts for c in p]) +
        b"\nPOLYGONS 4 16\n" + struct.pack(">16i", *[v for t in tris for v in (3,) + t]) + b"\n")
    put("mesh_vtk", "quad-strip-ascii.vtk", "# vtk DataFile Version 2.0\nq\nASCII\nDATASET POLYDATA\n"
        "POINTS 5 double\n0 0 0 1 0 0 1 1 0 0 1 0 0.5 0.5 1\nPOLYGONS 1 5\n4 0 1 2 3\n"
        "TRIANGLE_STRIPS 1 5\n4 0 1 4 2\n")
    put("mesh_vtk", "index-out-of-range.vtk", "# vtk DataFile Version 3.0\nbad\nASCII\nDATASET POLYDATA\n"
        "POINTS 3 float\n0 0 0 1 0 0 0 1 0\nPOLYGONS 1 4\n3 0 1 99999\n")
    put("mesh_vtk", "nan-points.vtk", "# vtk DataFile Version 3.0\nbad\nASCII\nDATASET POLYDATA\n"
        "POINTS 3 float\nnan 0 0 1 inf 0 0 1 0\nPOLYGONS 1 4\n3 0 1 2\n")
    for name in ["liver.vtk", "arteries.vtk"]:
        put("mesh_vtk", name.replace(".vtk", "-head1k.vtk"), read("fanslicer", name)[:1024])
    put("mesh_stl", "tetra-ascii.stl", "solid t\n" + "".join(
        "facet normal 0 0 0\nouter loop\n" + "".join("vertex %g %g %g\n" % pts[i] for i in t) +
        "endloop\nendfacet\n" for t in tris) + "endsolid t\n")
    put("mesh_stl", "tetra-binary.stl", b"tetra".ljust(80, b" ") + struct.pack("<I", 4) + b"".join(
        struct.pack("<12fH", 0, 0, 0, *[c for i in t for c in pts[i]], 0) for t in tris))
    put("mesh_stl", "binary-claims-4e9.stl", b"x".ljust(80, b" ") + struct.pack("<I", 0xFFFFFFFF) +
        struct.pack("<12fH", 0, 0, 0, *[c for i in tris[0] for c in pts[i]], 0))
    put("mesh_stl", "ascii-truncated.stl", "solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1")
    put("mesh_obj", "tetra.obj", "# tetra\no t\n" + "".join("v %g %g %g\n" % p for p in pts) +
        "vn 0 0 1\nvt 0 0\n" + "".join("f %d/1/1 %d/1/1 %d/1/1\n" % tuple(i + 1 for i in t) for t in tris))
    put("mesh_obj", "quad-negative.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf -4 -3 -2 -1\nf 1//1 2//1 3//1\n")
    put("mesh_obj", "garbage.obj", "v 1 2\nf 0 0 0\nf 1 2 999999\nv nan inf -inf\nvt\nmtllib x.mtl\n")
    ply_head = "ply\nformat %s 1.0\ncomment tetra\nelement vertex 4\nproperty float x\nproperty float y\n" \
        "property float z\nproperty uchar red\nelement face 4\nproperty list uchar int vertex_indices\nend_header\n"
    put("mesh_ply", "tetra-ascii.ply", ply_head % "ascii" + "".join("%g %g %g 7\n" % p for p in pts) +
        "".join("3 %d %d %d\n" % t for t in tris))
    for fmt, order in (("binary_little_endian", "<"), ("binary_big_endian", ">")):
        put("mesh_ply", "tetra-%s.ply" % fmt.split("_")[1], (ply_head % fmt).encode() +
            b"".join(struct.pack(order + "3fB", *p, 7) for p in pts) +
            b"".join(struct.pack(order + "B3i", 3, *t) for t in tris))
    put("mesh_ply", "x-only.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1 2\n")
    put("mesh_ply", "truncated.ply", ply_head % "ascii" + "0 0 0 7\n1 0 0 7\n")

    igtl_seeds()
    dicom_seeds()
    png_seeds()

    total = sum(os.path.getsize(os.path.join(d, f)) for d, _, fs in os.walk(OUT) for f in fs)
    print("fuzz/corpus: %d files, %d KB" % (sum(len(fs) for _, _, fs in os.walk(OUT)), total // 1024))


if __name__ == "__main__":
    main()
