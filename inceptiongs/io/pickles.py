"""Whether a file torch's weights-only loader refused is a pickle that names code.

InceptionGS writes tensors and plain data with ``torch.save`` (a zip archive) and reads them back
with ``weights_only=True``, which builds tensors and never imports or calls anything. A file that
loader refuses is either damaged bytes or a pickle asking to import and call something (a
payload, of any pickle protocol 0-5). The two get different answers: damaged bytes may fall back to
an older checkpoint; a payload refuses the run, so that nobody is told to load it unsafely.
"""

from __future__ import annotations

import pickletools
import zipfile
from pathlib import Path

# Opcodes that import a global or call one: only these let a pickle run code.
CODE_OPCODES = frozenset({"GLOBAL", "STACK_GLOBAL", "INST", "OBJ", "REDUCE", "NEWOBJ", "NEWOBJ_EX"})
# At most this many bytes are scanned (a payload names its globals near the start; a scan of a
# huge damaged file must not take long).
SCAN_BYTES = 64 << 20


def pickle_names_code(data: bytes) -> bool:
    """True when the pickle opcode stream ``data`` (any protocol) imports or calls a global.
    A stream that ends early or is damaged counts what was read before the damage."""
    try:
        for opcode, _, _ in pickletools.genops(data):
            if opcode.name in CODE_OPCODES:
                return True
    except Exception:  # noqa: BLE001 - pickletools raises several kinds for damaged streams
        pass
    return False


def file_names_code(path: str | Path, loader_message: str = "") -> bool:
    """Whether ``path`` names code: a bare pickle whose opcodes import or call a global, or a
    torch zip archive the weights-only loader refused for an unsupported global
    (``loader_message``: that loader's error)."""
    path = Path(path)
    try:
        if zipfile.is_zipfile(path):
            return "Unsupported global" in loader_message or "GLOBAL" in loader_message
        with open(path, "rb") as handle:
            return pickle_names_code(handle.read(SCAN_BYTES))
    except OSError:
        return False
