"""scipy's k-d tree (``cKDTree``) without the import of all of ``scipy.spatial``.

``from scipy.spatial import cKDTree`` runs scipy.spatial's ``__init__``, which also loads Qhull (with
scipy.linalg), the distance functions (with scipy.special) and ``transform``: start-up time the k-d tree does
not need. Its extension module ``scipy/spatial/_ckdtree`` needs only numpy, and names scipy.sparse (used only
by ``sparse_distance_matrix``, through the ``scipy`` package's lazy attribute) and one constant of
``scipy._lib._util``; those two import scipy's array-API layer, which loads much of numpy (f2py, testing).
So the extension is loaded by itself under its own name, with stand-ins for the two while it loads (removed
after: a later import finds the real modules); an import of scipy.spatial later finds it there and uses the
same class. Where scipy lays its files out otherwise (or scipy.spatial is loaded already), the ordinary import.
"""

from __future__ import annotations

import sys

_NAME = "scipy.spatial._ckdtree"
_SPARSE, _UTIL = "scipy.sparse", "scipy._lib._util"


def ckdtree_class() -> type:
    """``scipy.spatial.cKDTree``."""
    module = sys.modules.get(_NAME)
    if module is None and "scipy.spatial" not in sys.modules:
        module = _load_alone()
    if module is None:
        from scipy.spatial import cKDTree

        return cKDTree
    return module.cKDTree


def _stand_ins() -> dict:
    """Modules to stand in for scipy.sparse and scipy._lib._util while the extension loads (those not loaded yet).
    A name a stand-in lacks is taken from the real module, imported then (a scipy whose extension reads more)."""
    import importlib
    import types

    import numpy as np

    def stand_in(name: str) -> types.ModuleType:
        module = types.ModuleType(name)

        def real(attr: str):
            if attr.startswith("__"):  # the import system's own questions (``__path__``): a plain module
                raise AttributeError(attr)
            if sys.modules.get(name) is module:
                del sys.modules[name]
            return getattr(importlib.import_module(name), attr)

        module.__getattr__ = real
        return module

    stand_ins = {name: stand_in(name) for name in (_SPARSE, _UTIL) if name not in sys.modules}
    if _UTIL in stand_ins and int(np.__version__.split(".")[0]) >= 2:
        stand_ins[_UTIL].copy_if_needed = None  # scipy's value from numpy 2 on
    return stand_ins


def _load_alone():
    """The extension module loaded without its package's ``__init__``, or None if it is not where expected."""
    import importlib.machinery
    import importlib.util
    from pathlib import Path

    import scipy

    spec = importlib.machinery.PathFinder.find_spec("_ckdtree", [str(Path(scipy.__file__).parent / "spatial")])
    if spec is None or not isinstance(spec.loader, importlib.machinery.ExtensionFileLoader):
        return None
    spec = importlib.util.spec_from_file_location(_NAME, spec.origin)
    stand_ins = _stand_ins()
    try:
        sys.modules.update(stand_ins)
        module = sys.modules[_NAME] = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        module.cKDTree  # noqa: B018 - the class it is loaded for
    except Exception:  # noqa: BLE001 - any failure: the ordinary import decides
        sys.modules.pop(_NAME, None)
        return None
    finally:
        for name, stand_in in stand_ins.items():
            if sys.modules.get(name) is stand_in:
                del sys.modules[name]
    return module


__all__ = ["ckdtree_class"]
