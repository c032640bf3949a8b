"""What a file is, from its bytes: the one place that knows the formats' signatures.

The service and the command lines read uploads and inputs by their content, not by their name,
and when a file is of a kind a command or an endpoint does not take, they say what it is ("this
is a PNG image; ..."), not that it failed to parse as what was expected.
"""

from __future__ import annotations

import io
import re
import zipfile
from dataclasses import dataclass

POINT_FORMATS = "PLY, XYZ/TXT, NPY, NPZ or OBJ vertices"
"""The point cloud formats every point-cloud input takes (with or without normals)."""
MESH_FORMATS = "OBJ, OFF, STL, PLY, GLB or glTF"
IMAGE_FORMATS = "PNG, JPEG, HEIC, WebP, AVIF, GIF, BMP or TIFF"


@dataclass(frozen=True)
class Kind:
    """A kind of file: ``family`` is image, points, mesh or other; ``name`` says it to a person
    ("a PNG image"); ``loader`` is the format the octree loader reads it as (None: not a shape);
    ``known`` is False for the fallbacks (text or binary data of no recognised format)."""

    family: str
    name: str
    loader: str | None = None
    known: bool = True


IMAGE_SIGNATURES = ((b"\x89PNG\r\n\x1a\n", "PNG"), (b"\xff\xd8\xff", "JPEG"), (b"GIF87a", "GIF"), (b"GIF89a", "GIF"),
                    (b"BM", "BMP"), (b"II*\x00", "TIFF"), (b"MM\x00*", "TIFF"), (b"\x00\x00\x01\x00", "ICO"))
OTHER_SIGNATURES = ((b"%PDF-", "a PDF document"), (b"\x1f\x8b", "a gzip archive"), (b"7z\xbc\xaf\x27\x1c", "a 7z archive"),
                    (b"Rar!", "a RAR archive"), (b"\x7fELF", "an executable (ELF)"), (b"MZ", "a Windows executable"),
                    (b"\x80\x02", "a Python pickle"), (b"\x80\x03", "a Python pickle"), (b"\x80\x04", "a Python pickle"),
                    (b"\x80\x05", "a Python pickle"), (b"<!DOCTYPE html", "an HTML page"), (b"<html", "an HTML page"))


COLUMN_NAMES = re.compile(r"^\s*[A-Za-z_]\w*(?:[\s,]+[A-Za-z_]\w*){2,}\s*$")
"""A text point list's header line of column names ("x y z", "X,Y,Z,Nx,Ny,Nz"): at least three
names, separated by spaces or commas, as spreadsheets and scanner software write them."""


def is_column_header(line: str) -> bool:
    """Whether ``line`` (a text point list's first line, its byte-order mark already removed)
    names its columns rather than holding numbers (NaN and inf are numbers, not names)."""
    return bool(COLUMN_NAMES.match(line)) and not all(
        t.lower() in ("nan", "inf", "infinity") for t in line.replace(",", " ").split())


def identify(data: bytes, filename: str | None = None) -> Kind:
    """The kind of file ``data`` is: magic numbers first, then text content, the file name's
    extension only where the bytes cannot tell (OFF/STL/glTF/OBJ).  Text that is none of the mesh
    formats and starts with a number is taken for an XYZ point list (its parser says if it is not
    one); other text and unrecognised binary data are of no format this project reads."""
    head = data[:512]
    if len(data) >= 84 and 84 + 50 * int.from_bytes(data[80:84], "little") == len(data):
        return Kind("mesh", "a binary STL mesh", "stl")      # its size is fixed by its count: checked first,
    for magic, name in IMAGE_SIGNATURES:                     # as its 80-byte header is free text
        if head.startswith(magic):
            return Kind("image", f"a {name} image")
    if head[:4] == b"RIFF" and head[8:12] == b"WEBP":
        return Kind("image", "a WebP image")
    if head[4:12] in (b"ftypheic", b"ftypheix", b"ftypmif1", b"ftypavif"):
        return Kind("image", "a HEIC/AVIF image")
    if head.startswith(b"\x93NUMPY"):
        return Kind("points", "a NumPy array (NPY)", "npy")
    if head.startswith(b"PK\x03\x04"):
        return _zip_kind(data)
    if head.startswith(b"ply"):
        return Kind("points", "a PLY file", "ply")
    if head.startswith(b"glTF"):
        return Kind("mesh", "a GLB mesh", "glb")
    for magic, name in OTHER_SIGNATURES:
        if head.lstrip().startswith(magic) if magic.startswith(b"<") else head.startswith(magic):
            return Kind("other", name)
    ext = (filename or "").rpartition(".")[2].lower() if "." in (filename or "") else ""
    text = head.lstrip()
    if text.startswith(b"OFF"):
        return Kind("mesh", "an OFF mesh", "off")
    if text.startswith(b"solid") or ext == "stl":
        return Kind("mesh", "an STL mesh", "stl")
    if text.startswith(b"{") and (ext == "gltf" or b'"asset"' in data[:65536]):
        return Kind("mesh", "a glTF mesh", "gltf")
    if re.search(rb"^\s*(v|vn|f|o|g|mtllib)\s", head, re.M) and not re.match(rb"^\s*[-+.\d]", text):
        return Kind("points", "an OBJ file", "obj")
    if any(b < 9 or 13 < b < 32 for b in head):
        return Kind("other", "binary data of no format this project reads", known=False)
    if head.startswith(b"\xef\xbb\xbf"):                     # a UTF-8 byte-order mark
        head = head[3:]
    lines = [ln.strip() for ln in head.splitlines() if ln.strip() and not ln.lstrip().startswith((b"#", b"//"))]
    header = bool(lines) and is_column_header(lines[0].decode("utf-8", "replace"))
    if header:                                              # column names, then numbers
        lines = lines[1:]
    if (not lines and not header) or (lines and re.match(rb"[-+]?(\d|\.\d|nan|inf)", lines[0], re.I)):
        return Kind("points", "an XYZ point list", "xyz", known=False)   # its parser says what is wrong
    return Kind("other", "text in no format this project reads", known=False)


def _zip_kind(data: bytes) -> Kind:
    """An NPZ is a ZIP of .npy members; any other ZIP (an Office document, an archive) is not."""
    try:
        names = zipfile.ZipFile(io.BytesIO(data)).namelist()
    except zipfile.BadZipFile:
        return Kind("points", "a NumPy archive (NPZ)", "npz")    # damaged: its reader says how
    if names and all(n.endswith(".npy") for n in names):
        return Kind("points", "a NumPy archive (NPZ)", "npz")
    if any(n.startswith(("word/", "xl/", "ppt/")) for n in names):
        return Kind("other", "an Office document")
    return Kind("other", "a ZIP archive")


def not_taken(kind: Kind, takes: str) -> str:
    """The sentence for a file of a kind the reader does not take: what it is, what is taken."""
    return f"this is {kind.name}; {takes}"
