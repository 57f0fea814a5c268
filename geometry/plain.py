"""numpy values as plain Python, for the JSON and YAML files every layer writes (rig files, state files, results)."""

from __future__ import annotations

import numpy as np


def plain(value: object) -> object:
    """numpy scalars and arrays as Python numbers and lists, also inside dicts (keys as str), lists and tuples.

    Also the `default=` of json.dump(s), which calls it only for what JSON cannot write itself. A value that is
    neither numpy nor plain data is a TypeError (as json's own), not written under another type.
    """
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if value is None or isinstance(value, str | int | float | bool):
        return value
    raise TypeError(f"{type(value).__name__} is not plain data (JSON or YAML cannot hold it)")
