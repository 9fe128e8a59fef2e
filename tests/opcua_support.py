"""The official OPC UA nodesets (read in place from ../shared/opcua, never copied) and browsing helpers for the
OPC UA tests."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from lxml import etree
from shared_refs import shared_path

NS = "{http://opcfoundation.org/UA/2011/03/UANodeSet.xsd}"
UA = "http://opcfoundation.org/UA/"
FILES = ("Opc.Ua.Di.NodeSet2.xml", "Opc.Ua.IA.NodeSet2.xml", "Opc.Ua.Machinery.NodeSet2.xml",
         "opc.ua.isa95-jobcontrol.nodeset2.xml", "Opc.Ua.Machinery.Jobs.Nodeset2.xml",
         "Opc.Ua.MachineTool.NodeSet2.xml", "Opc.Ua.Machinery.Result.NodeSet2.xml", "opc.ua.gms.nodeset2.xml")
HAS_SUBTYPE, HAS_TYPEDEF = "i=45", "i=40"
HIERARCHICAL = {"i=47", "i=46", "i=35", "i=17604", "i=24136"}  # HasComponent, HasProperty, Organizes, HasAddIn ...


def shared_dir() -> Path | None:
    """The official nodesets, read in place: CMM_SHARED, else the shared folder beside the checkout."""
    folder = shared_path("opcua")
    return folder if (folder / FILES[-1]).is_file() else None


@dataclass
class Official:
    node_class: str
    browse_name: tuple[str, str]  # (namespace URI, name)
    refs: list[tuple[str, bool, tuple[str, str]]] = field(default_factory=list)  # (ref type, forward, target)

    def target(self, ref: str, forward: bool = True) -> tuple[str, str] | None:
        return next((t for r, f, t in self.refs if r == ref and f == forward), None)


def load_official(folder: Path) -> dict[tuple[str, str], Official]:
    """Every node of the official nodesets: (namespace URI, "i=N") -> its class, browse name and references."""
    nodes: dict[tuple[str, str], Official] = {}
    for name in FILES:
        root = etree.parse(str(folder / name)).getroot()
        uris = [u.text for u in root.find(NS + "NamespaceUris")]
        aliases = {a.get("Alias"): a.text for a in root.find(NS + "Aliases")}

        def nid(text: str) -> tuple[str, str]:
            text = aliases.get(text, text)
            if text.startswith("ns="):
                index, rest = text.split(";", 1)
                return uris[int(index[3:]) - 1], rest
            return UA, text

        def qname(text: str) -> tuple[str, str]:
            if ":" in text:
                index, rest = text.split(":", 1)
                if index.isdigit():
                    return (uris[int(index) - 1] if int(index) else UA), rest
            return UA, text

        for el in root:
            if not isinstance(el.tag, str) or not el.tag.startswith(NS + "UA"):
                continue
            refs_el = el.find(NS + "References")
            refs = [] if refs_el is None else [(aliases.get(r.get("ReferenceType"), r.get("ReferenceType")),
                                                r.get("IsForward", "true") != "false", nid(r.text)) for r in refs_el]
            refs = [(nid(r)[1] if not r.startswith("ns=") else r, f, t) for r, f, t in refs]
            nodes[nid(el.get("NodeId"))] = Official(el.tag[len(NS) + 2:], qname(el.get("BrowseName")), refs)
    return nodes


def declarations(nodes: dict, type_id: tuple[str, str]) -> dict[tuple[str, str], tuple[str, str] | None]:
    """The instance declarations of a type and its supertypes: browse name -> the declaration's type definition
    (the nearest type's declaration wins)."""
    out: dict[tuple[str, str], tuple[str, str] | None] = {}
    while type_id in nodes:
        t = nodes[type_id]
        for ref, forward, target in t.refs:
            if forward and ref in HIERARCHICAL and target in nodes:
                out.setdefault(nodes[target].browse_name, nodes[target].target(HAS_TYPEDEF))
        type_id = t.target(HAS_SUBTYPE, forward=False)
    return out


def is_subtype(nodes: dict, sub: tuple[str, str], sup: tuple[str, str]) -> bool:
    while sub is not None:
        if sub == sup:
            return True
        sub = nodes[sub].target(HAS_SUBTYPE, forward=False) if sub in nodes else None
    return False


UAX = "{http://opcfoundation.org/UA/2008/02/Types.xsd}"


def method_arguments(folder: Path) -> dict[tuple[str, str], dict[str, list[tuple[str, tuple[str, str]]]]]:
    """The official methods' arguments: (namespace URI, "i=N" of the method) -> {"InputArguments": [(name, data
    type (namespace URI, "i=N"))], "OutputArguments": [...]}."""
    out: dict[tuple[str, str], dict[str, list]] = {}
    for name in FILES:
        root = etree.parse(str(folder / name)).getroot()
        uris = [u.text for u in root.find(NS + "NamespaceUris")]

        def nid(text: str) -> tuple[str, str]:
            if text.startswith("ns="):
                index, rest = text.split(";", 1)
                return uris[int(index[3:]) - 1], rest
            return UA, text

        for el in root.iter(NS + "UAVariable"):
            kind = el.get("BrowseName")
            if kind not in ("InputArguments", "OutputArguments") or el.get("ParentNodeId") is None:
                continue
            args = [(a.findtext(UAX + "Name"), nid(a.find(UAX + "DataType").findtext(UAX + "Identifier").strip()))
                    for a in el.iter(UAX + "Argument")]
            out.setdefault(nid(el.get("ParentNodeId")), {})[kind] = args
    return out


def declaration_id(nodes: dict, type_id: tuple[str, str], browse_name: tuple[str, str]) -> tuple[str, str] | None:
    """The node of a type (or its supertypes) that declares ``browse_name``."""
    while type_id in nodes:
        for ref, forward, target in nodes[type_id].refs:
            if forward and ref in HIERARCHICAL and target in nodes and nodes[target].browse_name == browse_name:
                return target
        type_id = nodes[type_id].target(HAS_SUBTYPE, forward=False)
    return None
