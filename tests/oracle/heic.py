"""HEIC writer and independent reader for tests/heif.rs, through pillow-heif (PyPI; its own
bundled libheif and x265).

    heic.py write OUT.heic PHOTO.npy [--depth D.npy [--depth-sei-from APPLE.heic]] [--matte M.npy]
        [--aux URN=A.npy ...]
    heic.py read IN.heic OUTDIR

`write`: PHOTO.npy is H x W x 3 uint8; D.npy, M.npy and A.npy are h x w uint8. The images are
HEVC-coded by pillow-heif (x265) as one file of several top-level images, then the container is
edited per ISO/IEC 23008-12 so the second and later images become auxiliary images of the
first: an `auxC` property with the type URN (the depth one is `urn:mpeg:hevc:2015:auxid:2`;
the matte Apple's `urn:com:apple:photo:2018:aux:portraiteffectsmatte`), an `ipma` association
and an `auxl` item reference to the primary image; `iloc` offsets move with the grown `meta`
box. `--depth-sei-from` copies the depth `auxC`'s subtype (the ISO 23002-3 depth
representation SEI, as an iPhone wrote it) from an Apple HEIC, so the depth image states that
file's representation.

`read`: decodes what pillow-heif sees: photo.npy (H x W x 3 uint8, stored order), depth.npy
(raw samples) and depth.json (its metadata: d_min, d_max, representation_type...), and
aux.json with each auxiliary image's type and size, and aux_<id>.npy its samples.
"""
import json
import struct
import sys

import numpy as np
import pillow_heif

DEPTH_URN = "urn:mpeg:hevc:2015:auxid:2"
MATTE_URN = "urn:com:apple:photo:2018:aux:portraiteffectsmatte"


def boxes(b, start=0, end=None):
    """(type, payload_start, box_end) of the boxes in b[start:end]."""
    end = len(b) if end is None else end
    out = []
    i = start
    while i + 8 <= end:
        size, kind = struct.unpack(">I4s", b[i : i + 8])
        head = 8
        if size == 1:
            size = struct.unpack(">Q", b[i + 8 : i + 16])[0]
            head = 16
        elif size == 0:
            size = end - i
        out.append((kind.decode("latin1"), i + head, i + size))
        i += size
    return out


def box(kind, payload):
    return struct.pack(">I4s", 8 + len(payload), kind.encode("latin1")) + payload


def full(kind, version, flags, payload):
    return box(kind, struct.pack(">I", (version << 24) | flags) + payload)


def uint(b, at, n):
    return int.from_bytes(b[at : at + n], "big") if n else 0


def shift_iloc(payload, delta, threshold):
    """The iloc payload with every file offset at or after `threshold` moved by `delta`."""
    p = bytearray(payload)
    version = p[0]
    i = 4
    offset_size, length_size = p[i] >> 4, p[i] & 15
    base_size, index_size = p[i + 1] >> 4, (p[i + 1] & 15) if version in (1, 2) else 0
    i += 2
    id_size = 4 if version == 2 else 2
    count = uint(p, i, 2 if version < 2 else 4)
    i += 2 if version < 2 else 4
    for _ in range(count):
        i += id_size
        method = 0
        if version in (1, 2):
            method = uint(p, i, 2) & 15
            i += 2
        i += 2  # data_reference_index
        base_at = i
        base = uint(p, i, base_size)
        i += base_size
        extents = uint(p, i, 2)
        i += 2
        for _ in range(extents):
            i += index_size
            off = uint(p, i, offset_size)
            if method == 0 and base_size == 0 and off >= threshold:
                p[i : i + offset_size] = (off + delta).to_bytes(offset_size, "big")
            i += offset_size + length_size
        if method == 0 and base_size and base >= threshold:
            p[base_at : base_at + base_size] = (base + delta).to_bytes(base_size, "big")
    return bytes(p)


def depth_sei(path):
    """The subtype bytes of the depth auxC property of the HEIC `path`."""
    b = open(path, "rb").read()
    urn = DEPTH_URN.encode() + b"\0"
    i = b.index(urn)
    # size, 'auxC', version and flags, then the URN.
    size = struct.unpack(">I", b[i - 12 : i - 8])[0]
    assert b[i - 8 : i - 4] == b"auxC", "the depth URN is not in an auxC box"
    return b[i + len(urn) : i - 12 + size]


def make_auxiliary(data, aux):
    """`data` (a HEIF of 1 + len(aux) top-level images, items in order) with images 2.. made
    auxiliary images of image 1; aux: [(urn, subtype bytes)]."""
    top = boxes(data)
    meta = next(x for x in top if x[0] == "meta")
    children = boxes(data, meta[1] + 4, meta[2])
    get = {k: data[s:e] for k, s, e in children}
    # Item ids in iinf order: the primary first (pillow-heif writes them so).
    iinf = get["iinf"]
    n_items = uint(iinf, 4, 2 if iinf[0] == 0 else 4)
    entries = boxes(iinf, 4 + (2 if iinf[0] == 0 else 4))
    ids = []
    for kind, s, e in entries:
        if kind == "infe":
            version = iinf[s]
            ids.append(uint(iinf, s + 4, 2 if version < 3 else 4))
    assert len(ids) == n_items >= 1 + len(aux), (ids, aux)
    primary = uint(get["pitm"], 4, 2)
    assert primary == ids[0]
    # iprp: new auxC properties appended to ipco, associated in ipma.
    iprp = get["iprp"]
    parts = {k: iprp[s:e] for k, s, e in boxes(iprp)}
    ipco = parts["ipco"]
    n_props = len(boxes(ipco))
    ipco = ipco + b"".join(full("auxC", 0, 0, urn.encode() + b"\0" + sub) for urn, sub in aux)
    ipma = parts["ipma"]
    version, flags = ipma[0], uint(ipma, 1, 3)
    idw = 2 if version < 1 else 4
    big = flags & 1
    count = uint(ipma, 4, 4)
    i = 8
    assoc = {}
    order = []
    for _ in range(count):
        item = uint(ipma, i, idw)
        i += idw
        k = ipma[i]
        i += 1
        w = 2 if big else 1
        assoc[item] = [uint(ipma, i + j * w, w) for j in range(k)]
        order.append(item)
        i += k * w
    for j, item in enumerate(ids[1 : 1 + len(aux)]):
        index = n_props + 1 + j
        assoc.setdefault(item, []).append(index)
        if item not in order:
            order.append(item)
    body = struct.pack(">I", len(order))
    for item in order:
        body += item.to_bytes(idw, "big") + bytes([len(assoc[item])])
        body += b"".join(a.to_bytes(2 if big else 1, "big") for a in assoc[item])
    new_iprp = box("ipco", ipco) + full("ipma", version, flags, body)
    # iref: auxl from each auxiliary image to the primary.
    refs = b"".join(box("auxl", struct.pack(">HHH", item, 1, primary)) for item in ids[1 : 1 + len(aux)])
    old_iref = get.get("iref")
    if old_iref is not None:
        assert old_iref[0] == 0, "iref version 1 not handled"
        new_iref = full("iref", 0, 0, old_iref[4:] + refs)
    else:
        new_iref = full("iref", 0, 0, refs)
    out_children = []
    for kind, s, e in children:
        whole = data[s - 8 : e]
        if kind == "iprp":
            whole = box("iprp", new_iprp)
        elif kind == "iref":
            whole = new_iref
        out_children.append((kind, whole))
    if old_iref is None:
        at = [k for k, _ in out_children].index("iprp")
        out_children.insert(at, ("iref", new_iref))
    new_meta_payload = data[meta[1] : meta[1] + 4] + b"".join(w for _, w in out_children)
    new_meta = box("meta", new_meta_payload)
    old_meta_len = meta[2] - (meta[1] - 8)
    delta = len(new_meta) - old_meta_len
    # Move iloc's offsets past the old meta box by the growth.
    fixed = b""
    for kind, whole in out_children:
        if kind == "iloc":
            payload = shift_iloc(whole[8:], delta, meta[2])
            whole = whole[:8] + payload
        fixed += whole
    new_meta = box("meta", data[meta[1] : meta[1] + 4] + fixed)
    return data[: meta[1] - 8] + new_meta + data[meta[2] :]


def write(argv):
    out, photo = argv[0], np.load(argv[1])
    aux = []
    images = []
    i = 2
    while i < len(argv):
        flag = argv[i]
        if flag == "--depth":
            images.append((np.load(argv[i + 1]), DEPTH_URN, b""))
            i += 2
        elif flag == "--depth-sei-from":
            img, urn, _ = images[-1]
            images[-1] = (img, urn, depth_sei(argv[i + 1]))
            i += 2
        elif flag == "--matte":
            images.append((np.load(argv[i + 1]), MATTE_URN, b""))
            i += 2
        elif flag == "--aux":
            urn, path = argv[i + 1].split("=", 1)
            images.append((np.load(path), urn, b""))
            i += 2
        else:
            raise SystemExit(f"unknown argument {flag}")
    h, w = photo.shape[:2]
    heif = pillow_heif.from_bytes("RGB", (w, h), np.ascontiguousarray(photo, dtype=np.uint8).tobytes())
    for img, urn, sub in images:
        img = np.ascontiguousarray(img, dtype=np.uint8)
        heif.add_frombytes("L", (img.shape[1], img.shape[0]), img.tobytes())
        aux.append((urn, sub))
    import io

    buf = io.BytesIO()
    heif.save(buf, quality=-1)
    data = make_auxiliary(buf.getvalue(), aux) if aux else buf.getvalue()
    with open(out, "wb") as f:
        f.write(data)


def read(argv):
    path, outdir = argv
    heif = pillow_heif.open_heif(path, convert_hdr_to_8bit=False)
    np.save(f"{outdir}/photo.npy", np.asarray(heif))
    depths = heif.info.get("depth_images", [])
    if depths:
        d = depths[0]
        np.save(f"{outdir}/depth.npy", np.asarray(d))
        with open(f"{outdir}/depth.json", "w") as f:
            json.dump(d.info.get("metadata", {}), f)
    aux = []
    for urn, ids in heif.info.get("aux", {}).items():
        for item in ids:
            a = heif.get_aux_image(item)
            arr = np.asarray(a)
            np.save(f"{outdir}/aux_{item}.npy", arr)
            aux.append({"item_id": item, "aux_type": urn, "width": arr.shape[1], "height": arr.shape[0]})
    with open(f"{outdir}/aux.json", "w") as f:
        json.dump(aux, f)


if __name__ == "__main__":
    {"write": write, "read": read}[sys.argv[1]](sys.argv[2:])
