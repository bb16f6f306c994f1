"""The flat module paths of ``scenes/`` before its rooms (issue 41), kept importable for one release.

``from scenes.truth import project_points`` still works and warns (DeprecationWarning) where the name lives now.
The three old modules whose name is now a room's (``scenes.optics``, ``scenes.surfaces``, ``scenes.specimens``)
answer their old names from the room's own ``__getattr__``.
"""
from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings

#: Old module (under ``scenes.``) -> the modules its names live in now, searched in order.
OLD_PATHS = {
    "backend": ["scenes.optics.backend"],
    "camera": ["scenes.optics.camera"],
    "truth": ["scenes.optics.projection"],
    "speckle": ["scenes.surfaces.speckle"],
    "paint": ["scenes.surfaces.paint"],
    "image_texture": ["scenes.surfaces.image_texture"],
    "targets": ["scenes.surfaces.checkerboard", "scenes.surfaces.charuco", "scenes.surfaces.dot_grid"],
    "fields": ["scenes.deformation.displacement_field", "scenes.deformation.beam_bending",
               "scenes.deformation.fe_elements"],
    "motion": ["scenes.deformation.stage"],
    "surface_mesh": ["scenes.specimens.surface_mesh", "scenes.specimens.face_elements"],
    "mesh_specimen": ["scenes.specimens.mesh_specimen"],
    "fe_files": ["scenes.specimens.fe_files"],
    "fe_catalog": ["scenes.specimens.catalog"],
    "ray_surface": ["scenes.specimens.ray_surface"],
    "noise": ["scenes.sensor.noise"],
    "illumination": ["scenes.sensor.illumination"],
    "drift": ["scenes.sensor.drift"],
    "integrator": ["scenes.rendering.integrator"],
    "render": ["scenes.rendering.mitsuba"],
    "exact_render": ["scenes.rendering.exact"],
    "coverage_raster": ["scenes.rendering.coverage_raster"],
    "quadrature_raster": ["scenes.rendering.quadrature_raster"],
    "defocus_quadrature": ["scenes.rendering.defocus_quadrature", "scenes.rendering.defocus_rules"],
    "defocus_mesh": ["scenes.rendering.defocus_mesh"],
    "adaptive": ["scenes.rendering.adaptive"],
    "thin_lens_rays": ["scenes.rendering.thin_lens_rays"],
    "synthetic_images": ["scenes.image_pairs.analytic_fields", "scenes.image_pairs.gaussian_speckle",
                         "scenes.image_pairs.fourier_shift"],
    "star": ["scenes.image_pairs.star"],
}

#: Names that did not move but went, with what replaces them.
REMOVED = {
    ("fields", "FEMeshField"): "a user's FE result is read as a specimen: scenes.specimens.fe_files.read_specimen_file "
                               "(one FE path, issue 41)",
    ("fields", "check_covers_face"): "a specimen from an FE file is its own surface: "
                                     "scenes.specimens.fe_files.read_specimen_file",
}


class _Loader(importlib.abc.Loader):
    """Makes ``scenes.<old>`` a module whose attributes are looked up in the new modules, with a warning."""

    def create_module(self, spec):
        return None

    def exec_module(self, module):
        old = module.__name__
        targets = OLD_PATHS[old.split(".", 1)[1]]
        warnings.warn(f"{old} moved to {', '.join(targets)}; the old path goes in the next release",
                      DeprecationWarning, stacklevel=2)

        def __getattr__(name):
            gone = REMOVED.get((old.split(".", 1)[1], name))
            if gone:
                raise AttributeError(f"{old}.{name} was removed: {gone}")
            for target in targets:
                new = importlib.import_module(target)
                if hasattr(new, name):
                    return getattr(new, name)
            raise AttributeError(f"module {old!r} (moved to {', '.join(targets)}) has no attribute {name!r}")

        module.__getattr__ = __getattr__
        module.__doc__ = f"Moved to {', '.join(targets)} (deprecated path)."


class _Finder(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname, path=None, target=None):
        if fullname.startswith("scenes.") and fullname[len("scenes."):] in OLD_PATHS:
            return importlib.util.spec_from_loader(fullname, _Loader())
        return None


def moved_name(room: str, moved: dict[str, str], name: str):
    """A room package's ``__getattr__``: a name of the room's former flat module, from where it lives now, with a
    DeprecationWarning (``moved``: name -> its module now)."""
    if name in moved:
        warnings.warn(f"{room}.{name} moved to {moved[name]}.{name}; the old path goes in the next release",
                      DeprecationWarning, stacklevel=3)
        return getattr(importlib.import_module(moved[name]), name)
    raise AttributeError(f"module {room!r} has no attribute {name!r}")


def install() -> None:
    """Put the finder on ``sys.meta_path`` once (after the normal finders: a real module always wins)."""
    if not any(isinstance(f, _Finder) for f in sys.meta_path):
        sys.meta_path.append(_Finder())
