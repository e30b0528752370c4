"""The node's command line before rcl sees it. No ROS."""
from __future__ import annotations

import sys

from ..errors import UserError

MAX_PARAMS_FILE = 1 << 20  # bytes: a parameters file larger than this is refused


def check_params_files(argv) -> None:
    """Each --params-file read first by the schema's YAML loader (a regular UTF-8 file within its
    size, nesting, alias-expansion and duplicate-key limits) and refused here in one line: rcl
    would block on a FIFO, expand an alias bomb without end, silently take the last of two
    duplicate keys, or fail with its own multi-line error."""
    from .. import schema

    args = list(sys.argv[1:] if argv is None else argv)
    for flag, path in zip(args, args[1:], strict=False):
        if flag != "--params-file":
            continue
        what = schema.label(path, 160)
        try:
            text = schema.read_text_file(path, what, limit=MAX_PARAMS_FILE, kind="parameters file")
            schema.load_yaml(text, what=what)
        except UserError as error:
            text = str(error) if error.key == what else f"{what}: {error}"
            raise UserError("--params-file", text) from None
