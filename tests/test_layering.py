"""Layers run one way. Every import of the project's own modules is read from the source (top-level
and inside functions alike), so a lazy import that runs back up a layer is caught too."""
import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

# module prefix -> the project modules it may import (besides itself); checked on every file under it
LAYERS = {
    "latent_model.types": (),
    "latent_model.errors": (),
    "latent_model.atomic": (),
    "latent_model.runtime": (),
    "latent_model.topology": (),  # connectivity of any mesh: numpy only
    "latent_model.surface": ("latent_model.topology",),  # geometry of any mesh: numpy, scipy, libigl only
    "latent_model.render": (),
    "latent_model.corpus": ("latent_model.corpus", "latent_model.types", "latent_model.atomic", "latent_model.errors",
                            "latent_model.render", "latent_model.topology", "latent_model.runtime"),
    "latent_model.config": ("latent_model.corpus.config", "latent_model.types"),
    "latent_model.nn": ("latent_model.nn", "latent_model.config", "latent_model.types", "latent_model.errors",
                        "latent_model.topology"),
}
# inside inference, from the bottom up: a module never imports one that stands above it
INFERENCE_ORDER = ("latent_model.encoding", "latent_model.checkpoint", "latent_model.bank", "latent_model.transfer",
                   ("latent_model.predict", "latent_model.analysis"), "latent_model.cli", "explorer")
# inference: what a user's prediction runs through; it never imports training code
INFERENCE = ("latent_model.checkpoint", "latent_model.legacy", "latent_model.bank", "latent_model.encoding",
             "latent_model.transfer", "latent_model.predict", "latent_model.shipped", "latent_model.meshio",
             "latent_model.analysis", "latent_model.nn", "latent_model.corpus", "latent_model.config",
             "latent_model.surface", "explorer")


def project_imports() -> dict[str, set[str]]:
    """module name -> the project modules its source imports (latent_model.* / explorer.*)."""
    out = {}
    for path in [*ROOT.glob("latent_model/**/*.py"), *ROOT.glob("explorer/**/*.py")]:
        mod = ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
        names = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ImportFrom) and node.level:
                raise AssertionError(f"{path}: a relative import (use the absolute module name, so layers can be read)")
            if isinstance(node, ast.Import):
                names |= {a.name for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names |= {node.module} | {f"{node.module}.{a.name}" for a in node.names}
        out[mod] = {n for n in names if n.split(".")[0] in ("latent_model", "explorer")}
    return out


def _under(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


def test_inference_never_imports_training_code():
    bad = {m: sorted(n for n in names if _under(n, "latent_model.train"))
           for m, names in project_imports().items() if any(_under(m, p) for p in INFERENCE)}
    bad = {m: n for m, n in bad.items() if n}
    assert not bad, f"inference modules import latent_model.train: {bad}"


def test_layers_import_only_downwards():
    imports = project_imports()
    bad = {}
    for prefix, allowed in LAYERS.items():
        for mod, names in imports.items():
            if _under(mod, prefix):
                up = sorted(n for n in names if not _under(n, prefix) and not any(_under(n, a) for a in allowed)
                            and not any(_under(a, n) for a in allowed))  # `from latent_model import x` names a package
                if up:
                    bad[mod] = up
    assert not bad, f"imports that run back up a layer: {bad}"


def test_inference_modules_import_only_downwards():
    imports = project_imports()
    floors = [(f,) if isinstance(f, str) else f for f in INFERENCE_ORDER]
    bad = {}
    for i, floor in enumerate(floors):
        above = [m for f in floors[i + 1:] for m in f]
        for mod, names in imports.items():
            if any(_under(mod, m) for m in floor):
                up = sorted(n for n in names if any(_under(n, a) for a in above))
                if up:
                    bad[mod] = up
    assert not bad, f"inference modules import a module above them: {bad}"


def test_latent_model_never_imports_qt_or_explorer():
    assert not {m: n for m, n in project_imports().items()
                if m.startswith("latent_model") and any(_under(x, "explorer") for x in n)}
    code = ("import sys, latent_model.cli, latent_model.transfer, latent_model.meshio, latent_model.predict, "
            "latent_model.shipped, latent_model.analysis.report; latent_model.cli.build_parser(); "
            "bad = [m for m in sys.modules if m.startswith(('PySide6', 'pyvistaqt', 'explorer'))]; "
            "assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True)
