"""The paper's analyses (issue: evaluation); each analysis one module, `report.py` assembles them."""
