"""scipy's k-d tree loaded alone: the same neighbours as a brute-force search, and scipy's own modules intact."""

import subprocess
import sys
import textwrap

import numpy as np

from lio_cli.core.kdtree import ckdtree_class


def test_neighbours_match_brute_force():
    rng = np.random.default_rng(3)
    pts = rng.uniform(-10, 10, (2000, 3))
    queries = pts[::97]
    dist, idx = ckdtree_class()(pts, leafsize=64).query(queries, k=5)
    d2 = ((queries[:, None, :] - pts[None, :, :]) ** 2).sum(axis=2)
    expect = np.argsort(d2, axis=1)[:, :5]
    np.testing.assert_array_equal(idx, expect)
    np.testing.assert_allclose(dist, np.sqrt(np.take_along_axis(d2, expect, axis=1)), rtol=1e-12)


def test_loads_without_scipy_sparse_and_leaves_it_importable():
    # a fresh interpreter: this one may have loaded scipy.sparse or the k-d tree already
    code = textwrap.dedent("""
        import sys
        import numpy as np
        from lio_cli.core.kdtree import ckdtree_class
        cls = ckdtree_class()
        print(sorted(m for m in ("scipy.sparse", "scipy._lib._util", "scipy.spatial") if m in sys.modules))
        import scipy.sparse
        from scipy._lib._util import copy_if_needed
        from scipy.spatial import cKDTree
        tree = cls(np.eye(3))
        print(cKDTree is cls, copy_if_needed, type(tree.sparse_distance_matrix(tree, 2.0)).__name__,
              isinstance(tree.sparse_distance_matrix(tree, 2.0), scipy.sparse.dok_matrix))
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split("\n")
    assert out[0] == "[]"
    assert out[1] == "True None dok_matrix True"


def test_a_name_the_stand_in_lacks_comes_from_the_real_module():
    # as a scipy whose extension reads more of scipy._lib._util than the stand-in holds
    code = textwrap.dedent("""
        import sys
        import numpy as np
        from lio_cli.core import kdtree
        made = kdtree._stand_ins
        def lacking():
            stand_ins = made()
            vars(stand_ins[kdtree._UTIL]).pop("copy_if_needed", None)
            return stand_ins
        kdtree._stand_ins = lacking
        cls = kdtree.ckdtree_class()
        util = sys.modules["scipy._lib._util"]
        print(cls.__module__, util.__file__.endswith("_util.py"), cls(np.eye(3)).query([0.9, 0, 0], k=1)[1])
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["scipy.spatial._ckdtree", "True", "0"]
