"""coverage.npz: the evidence layers (mapping.evidence): per channel, the cells its footprint covered and where it
responded. The drill check (`arproj drill`, the projection session) judges by these, never by outlines."""

from __future__ import annotations

from pathlib import Path

from mapping.evidence import FILE_NAME
from mapping.exports.common import ExportJob

ORDER = 30


def write(job: ExportJob) -> Path:
    if job.result.coverage is None:
        raise ValueError("the map result has no coverage layer")
    return job.result.coverage.save(job.out_dir / FILE_NAME)
