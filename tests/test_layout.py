"""The package's layout rules: layers import only downward, nothing names a file
that is not in the repository, and no path of one machine is committed."""

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
#: layer -> the pcprep layers it may import (besides itself)
ALLOWED = {
    "filters": set(),
    "meshlab_bridge": {"filters"},
    "baselines": {"filters", "meshlab_bridge"},
}
#: third-party modules the algorithms must not need (arrays in, arrays out)
NOT_IN_FILTERS = {"pymeshlab", "dask", "laspy", "plyfile", "matplotlib", "CGAL", "sklearn"}


def _modules(layer):
    return sorted((ROOT / layer).rglob("*.py"))


def _imports(path):
    """Absolute names imported by ``path`` (relative imports resolved)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    rel = path.relative_to(ROOT).with_suffix("")
    package = ["pcprep", *rel.parts[:-1]]
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - node.level + 1]
                out.add(".".join(base + ([node.module] if node.module else [])))
            else:
                out.add(node.module)
    return out


@pytest.mark.parametrize("layer", sorted(ALLOWED))
def test_layers_import_only_downward(layer):
    for path in _modules(layer):
        for name in _imports(path):
            parts = name.split(".")
            assert parts[0] not in ALLOWED, f"{path}: imports {name} (use pcprep.{name})"
            if parts[0] == "pcprep" and len(parts) > 1 and parts[1] in ALLOWED:
                assert parts[1] == layer or parts[1] in ALLOWED[layer], \
                    f"{path.relative_to(ROOT)} imports {name}"
            if layer == "filters":
                assert parts[0] not in NOT_IN_FILTERS, f"{path}: imports {name}"


def test_the_namespace_root_is_the_only_top_level_package():
    import pcprep

    for sub in ("filters", "meshlab_bridge", "baselines"):
        mod = __import__(f"pcprep.{sub}", fromlist=["_"])
        assert Path(mod.__file__).resolve().parent == ROOT / sub or "site-packages" in \
            mod.__file__
    assert pcprep.__version__.count(".") == 2


_FILE_REF = re.compile(r"\b((?:docs|reports)/[\w./-]+\.(?:md|html|json|png))")


def test_package_text_names_only_files_in_the_repository():
    for layer in ALLOWED:
        for path in _modules(layer):
            text = path.read_text(encoding="utf-8")
            assert "ALGORITHMS.md" not in text, path
            for ref in _FILE_REF.findall(text):
                if "{" in ref or "quick" in ref:
                    continue  # formatted output names, generated on demand
                assert (ROOT / ref).exists(), f"{path.relative_to(ROOT)} names {ref}"


def test_no_absolute_path_of_one_machine_is_committed():
    machine = re.compile(r"(/work/|/root/|/home/\w+|/tmp/pcprep|C:\\\\Users)")
    files = [p for layer in (*ALLOWED, "pcprep", "tests") for p in (ROOT / layer).rglob("*.py")]
    files += [*ROOT.glob("reports/*.md"), *ROOT.glob("reports/*.json"),
              *ROOT.glob("reports/*.html"), ROOT / "README.md", *ROOT.glob("docs/**/*.md")]
    for path in files:
        if path.name == "test_layout.py":
            continue
        hit = machine.search(path.read_text(encoding="utf-8", errors="replace"))
        assert hit is None, f"{path.relative_to(ROOT)} holds {hit.group(0)!r}"


def test_the_models_folder_is_found_from_where_the_user_runs(tmp_path, monkeypatch):
    """An installed package lives in site-packages, so the shared models are
    looked up from the current folder and its parents (or given explicitly)."""
    from pcprep.baselines import datasets, meshes

    models = tmp_path / "shared" / "data" / "models"
    models.mkdir(parents=True)
    checkout = tmp_path / "main"
    checkout.mkdir()
    monkeypatch.delenv("PCPREP_SHARED_MODELS", raising=False)
    monkeypatch.setattr(meshes, "_MODELS_ROOT", None)
    monkeypatch.chdir(checkout)
    assert datasets.shared_models_root() == models
    assert datasets.models_hint() is None
    other = tmp_path / "elsewhere"
    other.mkdir()
    monkeypatch.setenv("PCPREP_SHARED_MODELS", str(other))
    assert datasets.shared_models_root() == other
    given = tmp_path / "given"
    given.mkdir()
    assert datasets.use_models_root(given) == given.resolve()
    assert datasets.shared_models_root() == given.resolve()
    monkeypatch.setattr(meshes, "_MODELS_ROOT", None)
    monkeypatch.setenv("PCPREP_SHARED_MODELS", str(tmp_path / "missing"))
    assert "--models" in datasets.models_hint()
    with pytest.raises(FileNotFoundError, match="does not exist"):
        datasets.use_models_root(tmp_path / "missing")
