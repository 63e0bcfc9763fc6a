"""The model package stands alone: importing all of it pulls in neither Qt nor the explorer."""
import subprocess
import sys


def test_latent_model_never_imports_qt_or_explorer():
    code = ("import sys, latent_model.cli, latent_model.transfer, latent_model.meshio, latent_model.predict, "
            "latent_model.shipped, latent_model.analysis.report; latent_model.cli.build_parser(); "
            "bad = [m for m in sys.modules if m.startswith(('PySide6', 'pyvistaqt', 'explorer'))]; "
            "assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True)
