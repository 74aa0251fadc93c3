"""The channel names of an OpenEXR file, read from its header, and the passes Blender makes of
them, so that the add-on can show a frame's denoised layer: Blender does not give Python a
multilayer image's pixels or pass names."""

import struct

MAGIC = b"\x76\x2f\x31\x01"
# Most header bytes read; tessera's headers are a few hundred.
MAX_HEADER = 1 << 20


def channel_names(path):
    """The file's channel names, in the file's (sorted) order; [] if it is not an EXR."""
    with open(path, "rb") as f:
        head = f.read(MAX_HEADER)
    if head[:4] != MAGIC:
        return []
    at = 8
    while at < len(head):
        name, at = _string(head, at)
        if not name:
            return []
        kind, at = _string(head, at)
        (size,) = struct.unpack_from("<i", head, at)
        at += 4
        if name == "channels" and kind == "chlist":
            return _channels(head[at : at + size])
        at += size
    return []


def _string(data, at):
    end = data.index(b"\0", at)
    return data[at:end].decode("utf-8", "replace"), end + 1


def _channels(data):
    names, at = [], 0
    while at < len(data) and data[at] != 0:
        name, at = _string(data, at)
        names.append(name)
        at += 16  # pixel type, pLinear and reserved, x and y sampling
    return names


def blender_passes(path):
    """The passes Blender lists for the file, in its order: `Combined` for the bare R, G, B,
    then each layer (the part of a channel name before its first dot), as the file sorts them."""
    passes = []
    for name in channel_names(path):
        first = name.split(".")[0] if "." in name else "Combined"
        if first not in passes:
            passes.append(first)
    if "Combined" in passes:
        passes.remove("Combined")
        passes.insert(0, "Combined")
    return passes
