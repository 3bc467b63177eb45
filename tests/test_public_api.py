"""Every advertised public name resolves, and the lazy import stays lazy."""

import subprocess
import sys

import seed2gs_inverse as sgi


def test_all_public_names_resolve():
    for name in sgi.__all__:
        assert getattr(sgi, name) is not None, name
    assert set(sgi.__all__) <= set(dir(sgi))


def test_unknown_name_is_attribute_error():
    try:
        sgi.no_such_thing
    except AttributeError as exc:
        assert "no_such_thing" in str(exc)
    else:
        raise AssertionError("expected AttributeError")


def test_import_does_not_load_heavy_modules():
    code = ("import sys, seed2gs_inverse; "
            "print(sorted(m for m in ('numba', 'cv2', 'onnxruntime', 'pyvista', 'matplotlib') "
            "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_operator_core_and_raster_names():
    from seed2gs_inverse import operators, raster, solvers

    assert set(operators.__all__) == {"ViewOperator", "OperatorStack", "Rendering", "as_stack", "dottest",
                                      "scene_fingerprint"}
    assert set(raster.__all__) == {"render", "build_operator", "project_gaussians", "Projection", "cone_cull",
                                   "FrozenScene", "MODES"}
    assert {"get_method", "method_options", "MethodResult"} <= set(solvers.__all__)
    assert sgi.FrozenScene is raster.FrozenScene and sgi.as_stack is operators.as_stack
    assert sgi.Rendering is operators.Rendering and not hasattr(sgi, "frozen")


def test_public_names_stay_themselves_after_every_submodule_is_imported():
    """Importing a submodule binds its name on the package: a submodule named like a public function
    (``seed2gs_inverse.compare`` once was) replaced that function by the module for everyone after it."""
    import importlib
    import pkgutil
    import types

    import seed2gs_inverse as sgi

    for info in pkgutil.walk_packages(sgi.__path__, "seed2gs_inverse."):
        if ".cli" in info.name or info.name.endswith("__main__"):
            continue
        importlib.import_module(info.name)
    for name in sgi.__all__:
        assert not isinstance(getattr(sgi, name), types.ModuleType), name
