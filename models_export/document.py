"""What the exporter reads of a model document (docs/model-format.md) beyond its terms: the hash.

The exporter depends on the document format only, never on the host classes that fit models;
host/learning/documents.py uses this same hash when it saves a document.
"""
import hashlib
import json


def canonical(doc):
    """The document without its provenance block as canonical JSON bytes (sorted keys, no spaces)."""
    body = {k: v for k, v in doc.items() if k != "provenance"}
    return json.dumps(body, sort_keys=True, separators=(",", ":")).encode()


def document_hash(doc):
    """sha256 hex of the document without its provenance block."""
    return hashlib.sha256(canonical(doc)).hexdigest()
