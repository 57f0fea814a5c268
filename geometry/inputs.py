"""Reading the files a person hands in: bounded before anything is allocated, checked value by value, and one
clear line (an InputError naming the file, key and value and what to do) when something is wrong.

Every reader of a user-supplied file (wall, scene, rig and camera_info, site file, objects.json, npz layers and
range images, scan logs, image sets) takes its bytes, its parsed document and its numbers from here, so that the
bounds and the wording are the same everywhere:

- `read_bytes` / `read_text`: missing, a folder, unreadable, larger than the kind of file can be (checked from
  the size on disk, before reading), binary where text is expected.
- `parse_yaml` / `parse_json` / `load_document`: PyYAML's safe loader with bounds checked while composing,
  before anything is expanded: nesting depth, and the number of nodes with aliases expanded (an alias bomb is
  refused after MAX_NODES nodes, not after expanding a billion); integers too long to be numbers. JSON with the
  same depth bound and without NaN/Infinity constants.
- value checks: `number`, `integer`, `boolean`, `text`, `choice`, `float_array` (types, finite, in a physical
  range, sizes bounded before an array is made).
- `NpzFile`: an .npz read without pickles, each array's header (dtype, shape) checked before it is read.
"""

from __future__ import annotations

import io
import json
import math
import reprlib
import tokenize
import zipfile
import zlib
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from geometry.errors import InputError

MAX_DOCUMENT_BYTES = 2**20       # a wall, scene, rig, camera_info or site file: hand-sized YAML/JSON
MAX_DEPTH = 64                   # nesting of mappings and lists; the deepest format needs 7
MAX_NODES = 100_000              # YAML nodes, aliases expanded: counted at ~10⁶/s, built at ~5·10⁴/s (loaded 2-core)
MAX_NPZ_BYTES = 2 * 2**30        # an .npz on disk
MAX_ARRAY_ELEMENTS = 2**28       # one array read from an .npz (2 GiB of float64)

_shown = reprlib.Repr()
_shown.maxstring, _shown.maxother, _shown.maxlist, _shown.maxtuple, _shown.maxdict, _shown.maxlevel = (
    60, 60, 6, 6, 4, 3)


def shown(value: Any) -> str:
    """A value as a message quotes it: short, one line, whatever it is (a 5,000-digit integer, a huge list)."""
    if isinstance(value, int) and not isinstance(value, bool) and value.bit_length() > 200:
        return f"<an integer of {int(value.bit_length() * 0.30103) + 1} digits>"
    if isinstance(value, (bytes, bytearray)):
        return f"<{len(value)} bytes of binary data>"
    if isinstance(value, np.ndarray):
        return f"<array of shape {value.shape}>" if value.size > 6 else repr(value.tolist())
    try:
        text = _shown.repr(value)
    except (ValueError, RecursionError):
        text = f"<{type(value).__name__}>"
    text = text.replace("\n", " ")
    return text if len(text) <= 80 else text[:77] + "..."


def fail(source: str, where: str, value: Any, what: str, hint: str | None = None) -> InputError:
    """The InputError for one bad value: `SOURCE: WHERE = VALUE: WHAT — HINT`."""
    return InputError(f"{source}: {where} = {shown(value)}: {what}", hint)


# -- bytes and text --------------------------------------------------------------------------------------------
def read_bytes(path: str | Path, what: str, max_bytes: int = MAX_DOCUMENT_BYTES, hint: str | None = None) -> bytes:
    """The bytes of a `what` file (e.g. "wall file"); InputError when missing, a folder, unreadable or larger
    than max_bytes (checked before reading). hint: what to do when it is missing."""
    path = Path(path)
    check_file(path, what, max_bytes, hint)
    try:
        return path.read_bytes()
    except OSError as err:
        raise InputError(f"{path}: cannot read the {what} ({err.strerror or err})") from None


def read_text(path: str | Path, what: str, max_bytes: int = MAX_DOCUMENT_BYTES, hint: str | None = None) -> str:
    """The UTF-8 text of a `what` file; binary content is refused (InputError) as read_bytes refuses the rest."""
    data = read_bytes(path, what, max_bytes, hint)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as err:
        raise InputError(f"{path}: not a text file (byte {err.start} is not UTF-8): not a {what}",
                         "is it the right file?") from None
    if "\x00" in text:
        raise InputError(f"{path}: holds binary data (a NUL byte at {text.index(chr(0))}): not a {what}",
                         "is it the right file?")
    return text


# -- documents -------------------------------------------------------------------------------------------------
_LOADER: type = getattr(yaml, "CSafeLoader", yaml.SafeLoader)  # libyaml's parser when there is one


def _check_yaml_bounds(text: str, source: str, hint: str | None) -> None:
    """Walk the parser's events (nothing is built) and refuse a document nested deeper than MAX_DEPTH or holding
    more than MAX_NODES nodes with every alias counted as the nodes it stands for: an alias bomb is refused
    after reading its few lines, never expanded."""
    nodes = 0
    sizes: dict[str, int] = {}              # anchor -> nodes it stands for
    opened: list[tuple[str | None, int]] = []  # open collections: (anchor, nodes before it)
    for event in yaml.parse(text, Loader=_LOADER):
        if isinstance(event, yaml.AliasEvent):
            nodes += sizes.get(event.anchor or "", 1)
        elif isinstance(event, yaml.ScalarEvent):
            nodes += 1
            if event.anchor is not None:
                sizes[event.anchor] = 1
        elif isinstance(event, yaml.CollectionStartEvent):
            opened.append((event.anchor, nodes))
            nodes += 1
            if len(opened) > MAX_DEPTH:
                raise InputError(f"{source}: refused: nested deeper than {MAX_DEPTH} levels",
                                 hint or "is it the right file?")
        elif isinstance(event, yaml.CollectionEndEvent) and opened:
            anchor, before = opened.pop()
            if anchor is not None:
                sizes[anchor] = nodes - before
        if nodes > MAX_NODES:
            raise InputError(f"{source}: refused: more than {MAX_NODES:,} values (aliases expanded)",
                             hint or "is it the right file?")


def parse_yaml(text: str, source: str, hint: str | None = None) -> Any:
    """A YAML document (safe types only), bounded as the module docstring says; InputError naming the source
    and the line otherwise."""
    try:
        _check_yaml_bounds(text, source, hint)
        return yaml.load(text, Loader=_LOADER)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(err, "problem", None) or str(err).splitlines()[0]
        raise InputError(f"{source}: not valid YAML{where} ({problem})", hint) from None
    except (ValueError, OverflowError, RecursionError, TypeError) as err:
        # e.g. an integer of more than 4,300 digits (int() refuses it), a timestamp out of range
        raise InputError(f"{source}: a value cannot be read ({_reason(err)})", hint) from None


def _no_constant(name: str) -> float:
    raise ValueError(f"{name} is not a number JSON allows")


def parse_json(text: str, source: str, hint: str | None = None, constants: bool = False) -> Any:
    """A JSON document nested at most MAX_DEPTH deep, without NaN/Infinity unless constants (Python's json
    writes them for float NaN); InputError otherwise."""
    try:
        document = json.loads(text, parse_constant=None if constants else _no_constant)
    except json.JSONDecodeError as err:
        raise InputError(f"{source}: not valid JSON at line {err.lineno}, column {err.colno} ({err.msg})",
                         hint) from None
    except RecursionError:
        raise InputError(f"{source}: refused: nested deeper than {MAX_DEPTH} levels", hint) from None
    except ValueError as err:  # a constant refused above, an integer of more than 4,300 digits
        raise InputError(f"{source}: a value cannot be read ({_reason(err)})", hint) from None
    check_depth(document, source)
    return document


def check_depth(document: Any, source: str, limit: int = MAX_DEPTH) -> None:
    """InputError when lists/mappings nest deeper than limit (checked without recursion)."""
    stack: list[tuple[Any, int]] = [(document, 1)]
    while stack:
        node, depth = stack.pop()
        children = node.values() if isinstance(node, dict) else node if isinstance(node, list) else None
        if children is None:
            continue
        if depth > limit:
            raise InputError(f"{source}: refused: nested deeper than {limit} levels", "is it the right file?")
        stack.extend((child, depth + 1) for child in children if isinstance(child, (dict, list)))


def load_document(path: str | Path, what: str, hint: str | None = None,
                  max_bytes: int = MAX_DOCUMENT_BYTES) -> Any:
    """A YAML (or, for a .json suffix, JSON) `what` file, read and parsed within the bounds above."""
    text = read_text(path, what, max_bytes, hint)
    if Path(path).suffix.lower() == ".json":
        return parse_json(text, str(path), hint)
    return parse_yaml(text, str(path), hint)


# -- values ----------------------------------------------------------------------------------------------------
def is_number(value: Any) -> bool:
    """An int or float of the document (not a bool, not text)."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


def number(source: str, where: str, value: Any, lo: float = -math.inf, hi: float = math.inf, unit: str = "",
           hint: str | None = None) -> float:
    """value as a finite float within [lo, hi]; InputError naming source, key and value otherwise."""
    units = f" ({unit})" if unit else ""
    if not is_number(value):
        raise fail(source, where, value, f"must be a number{units}", hint)
    try:
        v = float(value)
    except OverflowError:
        v = math.inf
    if not math.isfinite(v):
        raise fail(source, where, value, f"must be a finite number{units}", hint)
    if not lo <= v <= hi:
        raise fail(source, where, value, f"must be between {lo:g} and {hi:g}{units}", hint)
    return v


def integer(source: str, where: str, value: Any, lo: int, hi: int, hint: str | None = None) -> int:
    """value as an int within [lo, hi] (a float with an integer value is taken); InputError otherwise."""
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if not isinstance(value, (int, np.integer)) or isinstance(value, (bool, np.bool_)):
        raise fail(source, where, value, "must be an integer", hint)
    if not lo <= value <= hi:
        raise fail(source, where, value, f"must be between {lo} and {hi}", hint)
    return int(value)


def boolean(source: str, where: str, value: Any, hint: str | None = None) -> bool:
    if not isinstance(value, bool):
        raise fail(source, where, value, "must be true or false", hint)
    return value


def text(source: str, where: str, value: Any, max_len: int = 1000, hint: str | None = None) -> str:
    if not isinstance(value, str) or "\x00" in value:
        raise fail(source, where, value, "must be text", hint)
    if len(value) > max_len:
        raise fail(source, where, value, f"is {len(value):,} characters; at most {max_len:,}", hint)
    return value


def choice(source: str, where: str, value: Any, allowed: Sequence[Any], hint: str | None = None) -> Any:
    if isinstance(value, (dict, list)) or value not in allowed:
        raise fail(source, where, value, f"must be one of {', '.join(str(a) for a in allowed)}", hint)
    return value


def mapping(source: str, where: str, value: Any, what: str = "a mapping", hint: str | None = None) -> dict:
    if not isinstance(value, dict):
        raise fail(source, where, value, f"must be {what}", hint)
    return value


def float_array(source: str, where: str, value: Any, shape: Sequence[int | None], lo: float = -math.inf,
                hi: float = math.inf, max_rows: int = 1_000_000, unit: str = "", hint: str | None = None
                ) -> NDArray[np.float64]:
    """value (nested lists of numbers) as a float64 array of `shape` (None: any length), every entry finite and
    within [lo, hi]. The row count is bounded before the array is made; text, booleans, nulls, ragged rows and
    integers too large for a float are refused."""
    dims = "x".join("n" if s is None else str(s) for s in shape)
    units = f", {unit}" if unit else ""
    expected = f"must be a list of {'' if dims == 'n' else dims + ' '}numbers{units}"
    if not isinstance(value, list) and not (isinstance(value, np.ndarray) and value.dtype.kind in "iuf"):
        raise fail(source, where, value, expected, hint)
    if len(value) > max_rows:
        raise fail(source, where, value, f"has {len(value):,} rows; at most {max_rows:,}", hint)
    if isinstance(value, list) and not _numbers_only(value, len(shape)):
        raise fail(source, where, value, expected, hint)  # numpy would take True as 1 and "1.5" as 1.5
    try:
        arr = np.asarray(value)
    except (ValueError, TypeError, OverflowError, RecursionError):
        raise fail(source, where, value, expected, hint) from None
    if arr.dtype.kind not in "iuf" or arr.ndim != len(shape) or any(
            s is not None and s != n for s, n in zip(shape, arr.shape, strict=True)):
        raise fail(source, where, value, expected, hint)
    arr = arr.astype(np.float64)
    if not np.all(np.isfinite(arr)):
        raise fail(source, where, value, f"{expected}, all finite", hint)
    if arr.size and (arr.min() < lo or arr.max() > hi):
        raise fail(source, where, value, f"has a value outside {lo:g}..{hi:g}{units}", hint)
    return arr


def _numbers_only(value: list, ndim: int) -> bool:
    """Whether nested lists `ndim` deep hold numbers only (no bool, text, null or deeper lists), without
    recursion."""
    stack: list[tuple[Any, int]] = [(value, 1)]
    while stack:
        node, depth = stack.pop()
        if depth < ndim:
            if not all(isinstance(v, list) for v in node):
                return False
            stack.extend((v, depth + 1) for v in node)
        elif not all(is_number(v) for v in node):
            return False
    return True


# -- npz -------------------------------------------------------------------------------------------------------
class NpzFile:
    """An .npz archive read safely: no pickles (object arrays are refused), each array's header checked
    (numeric or text dtype, at most max_elements) before its data is read, a damaged archive refused.

        with NpzFile(path, "coverage layer", hint) as z:
            z.names; z.array("covered", ndim=3, kinds="u")
    """

    def __init__(self, path: str | Path, what: str, hint: str | None = None,
                 max_bytes: int = MAX_NPZ_BYTES, max_elements: int = MAX_ARRAY_ELEMENTS) -> None:
        self.path, self.what, self.hint, self.max_elements = Path(path), what, hint, max_elements
        check_file(self.path, what, max_bytes, hint)
        try:
            self._zip = zipfile.ZipFile(self.path)
            names = self._zip.namelist()
        except (zipfile.BadZipFile, OSError, ValueError, EOFError) as err:
            raise InputError(f"{self.path}: not an .npz {what} ({_reason(err)})", hint) from None
        self.names = [n[:-4] for n in names if n.endswith(".npy")]

    def __enter__(self) -> NpzFile:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._zip.close()

    def __contains__(self, name: str) -> bool:
        return name in self.names

    def __iter__(self) -> Iterator[str]:
        return iter(self.names)

    def array(self, name: str, ndim: int | None = None, kinds: str = "iuf",
              shape: Sequence[int | None] | None = None) -> np.ndarray:
        """Array `name`: its dtype kind one of `kinds` (numpy kind letters: i u f b U), ndim or shape (None: any
        length) as given; the header is checked before the data are read."""
        if shape is not None:
            ndim = len(shape)
        where = f"{self.path}: array {name!r}"
        if name not in self.names:
            raise InputError(f"{where} is missing (it has: {', '.join(self.names[:12]) or 'none'})", self.hint)
        try:
            with self._zip.open(f"{name}.npy") as member:
                version = np.lib.format.read_magic(member)
                if version == (1, 0):
                    found, _, dtype = np.lib.format.read_array_header_1_0(member)
                elif version == (2, 0):
                    found, _, dtype = np.lib.format.read_array_header_2_0(member)
                else:
                    raise ValueError(f"npy format version {version}")
                if dtype.kind not in kinds or dtype.hasobject:
                    raise InputError(f"{where} holds {dtype} values, expected "
                                     f"{'/'.join(_KIND_NAMES.get(k, k) for k in kinds)}", self.hint)
                if (ndim is not None and len(found) != ndim) or (shape is not None and any(
                        s is not None and s != n for s, n in zip(shape, found, strict=True))):
                    expected = "x".join("n" if s is None else str(s) for s in shape) if shape is not None else \
                        f"{ndim} dimension(s)"
                    raise InputError(f"{where} has shape {found}, expected {expected}", self.hint)
                if math.prod(found) > self.max_elements:
                    raise InputError(f"{where} has shape {found}: more than {self.max_elements:,} values",
                                     self.hint)
            with self._zip.open(f"{name}.npy") as member:
                data = member.read()  # to its end, so that zipfile checks the CRC-32 (a flipped bit shows)
            return np.lib.format.read_array(io.BytesIO(data), allow_pickle=False)
        except InputError:
            raise
        # a damaged header reaches numpy's parser: literal_eval's SyntaxError, then its tokenizer's TokenError
        except (ValueError, OSError, EOFError, zipfile.BadZipFile, KeyError, RuntimeError, zlib.error, SyntaxError,
                tokenize.TokenError) as err:
            raise InputError(f"{where} cannot be read ({_reason(err)}): a damaged {self.what}", self.hint) from None

    def floats(self, name: str, shape: Sequence[int | None], finite: bool = True) -> NDArray[np.float64]:
        """Array `name` as float64 of `shape` (None: any length), finite unless finite=False (NaN allowed)."""
        arr = self.array(name, kinds="iuf", shape=shape).astype(np.float64)
        if finite and not np.all(np.isfinite(arr)):
            raise InputError(f"{self.path}: array {name!r} holds values that are not finite numbers", self.hint)
        return arr


_KIND_NAMES = {"i": "integer", "u": "unsigned", "f": "float", "b": "bool", "U": "text"}


def check_file(path: Path, what: str, max_bytes: int, hint: str | None) -> None:
    """InputError unless path is a file of at most max_bytes (its content is not read)."""
    try:
        if path.is_dir():
            raise InputError(f"{path}: is a folder, not a {what}", hint)
        size = path.stat().st_size
    except FileNotFoundError:
        raise InputError(f"{path}: no such {what}", hint) from None
    except OSError as err:
        raise InputError(f"{path}: cannot read the {what} ({err.strerror or err})") from None
    if size > max_bytes:
        raise InputError(f"{path}: {size:,} bytes is too large for a {what} (at most {max_bytes:,})",
                         "is it the right file?")


def _reason(err: BaseException) -> str:
    """An exception's first line, short; Python's digit limit in a person's words."""
    text = str(err).splitlines()[0] if str(err) else type(err).__name__
    if "integer string conversion" in text:
        return "a number of more than 4,300 digits"
    return text[:120]


# -- images ----------------------------------------------------------------------------------------------------
MAX_IMAGE_BYTES = 512 * 2**20
MAX_IMAGE_SIDE = 16384  # pixels per side of a photo (a 100-megapixel camera is 12,000 wide)


def read_image(path: str | Path, what: str = "image file", grey: bool = True, hint: str | None = None
               ) -> NDArray[np.uint8]:
    """An image file as uint8 (grey, or BGR as OpenCV reads it); InputError naming the file when it is missing,
    not an image, or larger than MAX_IMAGE_SIDE per side (read from its header before it is decoded)."""
    import cv2
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    hint = hint or "remove it or replace it with a JPEG/PNG capture"
    check_file(path, what, MAX_IMAGE_BYTES, hint)
    too_large = InputError(f"{path}: larger than any camera of this system takes (at most {MAX_IMAGE_SIDE} "
                           "pixels per side)", hint)
    try:
        with Image.open(path) as header:  # reads the header only
            width, height = header.size
    except Image.DecompressionBombError:
        raise too_large from None
    except (UnidentifiedImageError, OSError, ValueError):
        width = height = 0  # not a format Pillow knows (OpenCV may), or damaged: OpenCV decides below
    if max(width, height) > MAX_IMAGE_SIDE:
        raise InputError(f"{path}: {width}x{height} pixels is larger than any camera of this system takes "
                         f"(at most {MAX_IMAGE_SIDE} per side)", hint)
    try:
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE if grey else cv2.IMREAD_COLOR)
    except cv2.error:  # OpenCV's own size limit, a decoder's assertion
        raise too_large from None
    if image is None or image.size == 0:
        raise InputError(f"{path}: not a readable image", hint)
    return np.asarray(image, dtype=np.uint8)
