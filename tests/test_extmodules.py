"""Extension modules of other packages loaded without their package's ``__init__``."""

import json
import subprocess
import sys

from surfidx.extmodules import load_extension, scipy_spatial


def test_a_missing_extension_or_package_is_none():
    assert load_extension("scipy.spatial", "_no_such_extension") is None
    assert load_extension("no_such_package_surfidx", "_ext") is None
    assert "scipy.spatial._no_such_extension" not in sys.modules


def test_an_imported_extension_is_the_loaded_one():
    import scipy.spatial

    assert scipy_spatial("_qhull").ConvexHull is scipy.spatial.ConvexHull
    assert scipy_spatial("_no_such_extension") is scipy.spatial


def test_loaded_alone_then_the_package_imports_the_same_module():
    """Loaded before its package, the extension is the module the package's later import
    uses: one copy, the same classes."""
    code = ("import sys, json\n"
            "import numpy as np\n"
            "from surfidx.extmodules import scipy_spatial\n"
            "hull = scipy_spatial('_qhull')\n"
            "tree = scipy_spatial('_ckdtree')\n"
            "alone = 'scipy.spatial' not in sys.modules\n"
            "pts = np.random.default_rng(0).normal(size=(50, 3))\n"
            "n = len(hull.ConvexHull(pts).simplices)\n"
            "d, i = tree.cKDTree(pts).query(pts, k=2)\n"
            "import scipy.spatial\n"
            "same = (scipy.spatial.ConvexHull is hull.ConvexHull\n"
            "        and scipy.spatial.cKDTree is tree.cKDTree\n"
            "        and scipy.spatial.QhullError is hull.QhullError)\n"
            "print(json.dumps([alone, same, n > 0, bool((i[:, 0] == np.arange(50)).all())]))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, check=True).stdout
    assert json.loads(out.splitlines()[-1]) == [True, True, True, True]
