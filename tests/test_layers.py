"""ocalib's packages form layers: each imports only from layers below it (or from itself), so there is no import
cycle and no package reaches up. Lazy imports inside functions count too."""

import ast
from importlib.util import find_spec
from pathlib import Path

import ocalib

PACKAGE = Path(ocalib.__file__).parent
TRAIN = Path(find_spec("ocalib.train").submodule_search_locations[0])  # the top-level folder train/, installed there

# Bottom first; a package imports only from the layers before its own.
LAYERS = [
    {"errors"},  # the one error users see (InputError) and Ctrl-C handling
    {"geometry"},  # poses, quaternions, angles: the conventions in code
    {"io"},  # pose files, timestamps, JSON values
    {"data", "models", "calib", "viz"},  # sequences on disk; the networks; the calibration math; figures
    {"losses", "synth", "sim"},  # the training losses; the renderer; the paper's simulation
    {"frontend"},  # ego-motion from images: the network, OpenCV VO, photometric alignment
    {"inference"},  # running a trained network over a sequence, and exporting it
    {"eval"},  # errors against the truth: trajectories, depth, calibrations
    {"rigba"},  # the rig bundle adjustment on COLMAP, batch and on-line
    {"calibnet", "train"},  # calibrating a rig from its images: front end -> head -> rig estimator -> adjustment;
    # training the networks (Lightning)
    {"cli"},  # the ocalib command
]


def _package(path: Path) -> str | None:
    if path.is_relative_to(TRAIN):
        return "train"
    parts = path.relative_to(PACKAGE).parts
    return parts[0].removesuffix(".py") if parts[0] not in ("__init__.py", "__main__.py") else None


def _imports(path: Path) -> set[str]:
    """The ocalib packages that the module at ``path`` imports."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        names = [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else []
        names += [a.name for a in node.names] if isinstance(node, ast.Import) else []
        out.update(n.split(".")[1] for n in names if n.startswith("ocalib."))
    return out


def test_every_package_imports_only_from_the_layers_below_it():
    layer = {name: i for i, names in enumerate(LAYERS) for name in names}
    upward = []
    for path in sorted(PACKAGE.rglob("*.py")) + sorted(TRAIN.rglob("*.py")):
        package = _package(path)
        if package is None:  # ocalib/__init__.py (the public API, loaded lazily) and __main__.py sit on top
            continue
        assert package in layer, f"{package} is in no layer of LAYERS"
        upward += [f"{path.relative_to(PACKAGE)} imports ocalib.{dep}" for dep in _imports(path)
                   if dep != package and layer[dep] >= layer[package]]  # fmt: skip
    assert not upward, upward


def test_the_layers_name_every_package_once():
    names = [name for names in LAYERS for name in names]
    assert len(names) == len(set(names))
    on_disk = {p.name for p in PACKAGE.iterdir() if (p / "__init__.py").exists() or p.suffix == ".py"}
    assert {n.removesuffix(".py") for n in on_disk} - {"__init__", "__main__"} | {"train"} == set(names)


# calib's sub-packages, bottom first: the stages, the drivers that chain them, the calibrate-poses application.
CALIB_LAYERS = ["stages", "drivers", "poses"]


def test_calib_sub_packages_import_only_from_those_below():
    upward = []
    for i, sub in enumerate(CALIB_LAYERS):
        for path in sorted((PACKAGE / "calib" / sub).glob("*.py")):
            for node in ast.walk(ast.parse(path.read_text())):
                name = (node.module or "") if isinstance(node, ast.ImportFrom) else ""
                parts = name.split(".")
                if name.startswith("ocalib.calib.") and parts[2] in CALIB_LAYERS[i + 1 :]:
                    upward.append(f"{path.relative_to(PACKAGE)} imports {name}")
    assert not upward, upward
    on_disk = {p.name for p in (PACKAGE / "calib").iterdir() if (p / "__init__.py").exists()}
    assert on_disk == set(CALIB_LAYERS)
    assert [p.name for p in (PACKAGE / "calib").glob("*.py")] == ["__init__.py"]
