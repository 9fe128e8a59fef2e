"""Validating QIF documents against the QIF 3.0.0 schemas in ../shared/qif (read in place, offline, with lxml).

The schemas are not part of the project: ``schema()`` returns None with the reason when the folder or lxml is
missing, and the tests skip with it.
"""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path

from shared_refs import shared_path

QIF_DIR = Path(os.environ.get("CMM_QIF_SCHEMAS", shared_path("qif")))
XMLDSIG = "http://www.w3.org/TR/2002/REC-xmldsig-core-20020212/xmldsig-core-schema.xsd"
NS = {"q": "http://qifstandards.org/xsd/qif3"}


@lru_cache(maxsize=1)
def _load():
    try:
        from lxml import etree
    except ImportError:
        return None, "lxml is not installed (pip install lxml): QIF documents cannot be validated"
    root = QIF_DIR / "schemas"
    xsd = root / "QIFApplications" / "QIFDocument.xsd"
    if not xsd.is_file():
        return None, f"the QIF 3.0.0 schemas are not at {root} (see ../shared/qif/README.md)"
    local = root / "QIFLibrary" / "xmldsig-core-schema.xsd"

    class Resolver(etree.Resolver):
        def resolve(self, url, pubid, context):
            if url == XMLDSIG or url.endswith("xmldsig-core-schema.xsd"):
                return self.resolve_filename(str(local), context)
            return None

    parser = etree.XMLParser(no_network=True)
    parser.resolvers.add(Resolver())
    return etree.XMLSchema(etree.parse(str(xsd), parser)), ""


def schema_or_skip():
    import pytest

    schema, why = _load()
    if schema is None:
        pytest.skip(why)
    return schema


def validate(path_or_bytes) -> "object":
    """Parse and validate; returns the lxml root. Raises AssertionError with the schema's errors."""
    from lxml import etree

    schema = schema_or_skip()
    if isinstance(path_or_bytes, (bytes, bytearray)):
        doc = etree.fromstring(bytes(path_or_bytes)).getroottree()
    else:
        doc = etree.parse(str(path_or_bytes))
    if not schema.validate(doc):
        errors = "\n".join(f"line {e.line}: {e.message}" for e in list(schema.error_log)[:15])
        raise AssertionError(f"the QIF document does not validate against QIF 3.0.0:\n{errors}")
    return doc.getroot()
