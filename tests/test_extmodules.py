"""Extension modules of other packages loaded without their package's ``__init__``."""

import json
import subprocess
import sys

from surfidx.extmodules import load_extension


def test_a_missing_extension_or_package_is_none():
    assert load_extension("pyshtools", "_no_such_extension") is None
    assert load_extension("no_such_package_surfidx", "_ext") is None
    assert "pyshtools._no_such_extension" not in sys.modules


def test_loaded_alone_then_the_package_imports_the_same_module():
    """Loaded before its package, the extension is the module the package's later import
    uses: one copy."""
    code = ("import sys, json\n"
            "from surfidx.extmodules import load_extension\n"
            "ext = load_extension('pyshtools', '_SHTOOLS')\n"
            "alone = 'pyshtools' not in sys.modules\n"
            "has = hasattr(ext, 'SHExpandDH')\n"
            "import pyshtools.backends.shtools\n"
            "same = sys.modules['pyshtools._SHTOOLS'] is ext\n"
            "print(json.dumps([alone, has, same]))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=300, check=True).stdout
    assert json.loads(out.splitlines()[-1]) == [True, True, True]
