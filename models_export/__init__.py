"""Model document (docs/model-format.md) to integer coefficient table (docs/table-format.md).

``export_model(doc)`` quantises the model for the firmware's integer
evaluation (firmware/evaluate.py), certifies integer safety and accuracy over
the model's envelope (models_export.certify) and returns an ``Export`` with the
table bytes, the report and the C header. Raises ``ExportError`` naming the
term when the model cannot be made integer-safe or accurate enough.
"""
from models_export.certify import LIMITS_UM, ExportError
from models_export.export import Export, export_model

__all__ = ["Export", "ExportError", "LIMITS_UM", "export_model"]
