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


def provenance(doc):
    """(actual sha256, the recorded provenance.sha256 or None). A recorded hash that differs from the actual one
    means the document was edited after it was saved: export refuses it and predict refuses it alike, unless
    told (``--allow-edited``)."""
    prov = doc.get("provenance")
    declared = prov.get("sha256") if isinstance(prov, dict) else None
    return document_hash(doc), declared


def edited_reason(declared, actual):
    """The one sentence both export and predict give for an edited document."""
    return ("provenance.sha256 %.16s... does not match the document (actual %.16s...): it was edited after it was "
            "saved; re-save it, or use it marked as edited (--allow-edited)" % (declared, actual))
