"""scipy's k-d tree (``cKDTree``) without the import of all of ``scipy.spatial``.

``from scipy.spatial import cKDTree`` runs scipy.spatial's ``__init__``, which also loads Qhull (with
scipy.linalg), the distance functions (with scipy.special) and ``transform``: start-up time the k-d tree does
not need. Its extension module ``scipy/spatial/_ckdtree`` needs only numpy and
scipy.sparse, so it is loaded by itself under its own name; an import of scipy.spatial later finds it there
and uses the same class. Where scipy lays its files out otherwise (or scipy.spatial is loaded already),
the ordinary import.
"""

from __future__ import annotations

import sys

_NAME = "scipy.spatial._ckdtree"


def ckdtree_class() -> type:
    """``scipy.spatial.cKDTree``."""
    module = sys.modules.get(_NAME)
    if module is None and "scipy.spatial" not in sys.modules:
        module = _load_alone()
    if module is None:
        from scipy.spatial import cKDTree

        return cKDTree
    return module.cKDTree


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
    try:
        module = sys.modules[_NAME] = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        module.cKDTree  # noqa: B018 - the class it is loaded for
    except Exception:  # noqa: BLE001 - any failure: the ordinary import decides
        sys.modules.pop(_NAME, None)
        return None
    return module


__all__ = ["ckdtree_class"]
