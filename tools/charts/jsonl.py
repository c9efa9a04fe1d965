"""JSON-lines reading shared by the chart scripts: every benchmark and the eval print one JSON
object per line; a line that is not JSON stops the script naming the file and line."""

import json
import sys


def read_jsonl(paths, tool):
    """Yields (path, line_number, object) for every non-empty line of the files."""
    for p in paths:
        with open(p, encoding="utf-8") as f:
            for n, line in enumerate(f, 1):
                line = line.strip()
                if not line:
                    continue
                try:
                    yield p, n, json.loads(line)
                except json.JSONDecodeError as e:
                    sys.exit(f"{tool}: {p}:{n}: not JSON: {e}")
