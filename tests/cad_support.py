"""STEP files the CAD tests write with OpenCASCADE (OCP): known geometry, several bodies, units, an assembly."""

from __future__ import annotations

from pathlib import Path


def write_step(shape, path: Path, unit: str = "MM", schema: str | None = None) -> Path:
    """Write a shape as STEP (AP214 by default; ``unit`` MM or INCH: the file's coordinates are in that unit)."""
    from OCP.Interface import Interface_Static
    from OCP.Message import Message_ProgressRange
    from OCP.STEPControl import STEPControl_AsIs, STEPControl_Controller, STEPControl_Writer

    STEPControl_Controller.Init_s()  # defines the write.step.* parameters (before the first writer they are unknown)
    Interface_Static.SetCVal_s("write.step.unit", unit)
    if schema:
        Interface_Static.SetCVal_s("write.step.schema", schema)
    try:
        writer = STEPControl_Writer()
        writer.Transfer(shape, STEPControl_AsIs, True, Message_ProgressRange())
        writer.Write(str(path))
    finally:
        Interface_Static.SetCVal_s("write.step.unit", "MM")
        Interface_Static.SetCVal_s("write.step.schema", "AP214CD")
    return Path(path)


def box_with_sphere_and_cone():
    """A 60 x 40 x 20 block (0..60, 0..40, 0..20) with a D20 sphere centred at (20, 20, 15) fused on top and a
    cone (R8 at z 20 to R4 at z 28, axis (45, 20, z)) with a flat top."""
    from OCP.BRepAlgoAPI import BRepAlgoAPI_Fuse
    from OCP.BRepPrimAPI import BRepPrimAPI_MakeBox, BRepPrimAPI_MakeCone, BRepPrimAPI_MakeSphere
    from OCP.gp import gp_Ax2, gp_Dir, gp_Pnt

    box = BRepPrimAPI_MakeBox(gp_Pnt(0, 0, 0), 60.0, 40.0, 20.0).Shape()
    shape = BRepAlgoAPI_Fuse(box, BRepPrimAPI_MakeSphere(gp_Pnt(20, 20, 15), 10.0).Shape()).Shape()
    cone = BRepPrimAPI_MakeCone(gp_Ax2(gp_Pnt(45, 20, 20), gp_Dir(0, 0, 1)), 8.0, 4.0, 8.0).Shape()
    return BRepAlgoAPI_Fuse(shape, cone).Shape()


def filleted_box(radius: float = 7.5):
    """A 60 x 40 x 20 block whose vertical edge at (60, 40) is rounded with ``radius`` (a cylinder tangent to two
    planes: the triangles' smooth region runs into both)."""
    from OCP.BRepAdaptor import BRepAdaptor_Curve
    from OCP.BRepFilletAPI import BRepFilletAPI_MakeFillet
    from OCP.BRepPrimAPI import BRepPrimAPI_MakeBox
    from OCP.TopAbs import TopAbs_EDGE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS
    from OCP.gp import gp_Pnt

    box = BRepPrimAPI_MakeBox(gp_Pnt(0, 0, 0), 60.0, 40.0, 20.0).Shape()
    fillet = BRepFilletAPI_MakeFillet(box)
    ex = TopExp_Explorer(box, TopAbs_EDGE)
    while ex.More():
        edge = TopoDS.Edge(ex.Current())
        c = BRepAdaptor_Curve(edge)
        a, b = c.Value(c.FirstParameter()), c.Value(c.LastParameter())
        if all(abs(v - w) < 1e-9 for v, w in ((a.X(), 60), (b.X(), 60), (a.Y(), 40), (b.Y(), 40))):
            fillet.Add(radius, edge)
        ex.Next()
    return fillet.Shape()


def bolt_assembly(path: Path) -> Path:
    """An assembly (XCAF): one product 'plate' (a 50 x 30 x 10 block with a D10 through hole at (15, 15)) placed
    twice, at the origin and moved by (0, 0, 10) and turned 90° about Z around (25, 15), plus a product 'pin'
    (D10 cylinder, 30 long, axis (15, 15, z)) in the hole of the first."""
    from OCP.BRepAlgoAPI import BRepAlgoAPI_Cut
    from OCP.BRepPrimAPI import BRepPrimAPI_MakeBox, BRepPrimAPI_MakeCylinder
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.Message import Message_ProgressRange
    from OCP.STEPCAFControl import STEPCAFControl_Writer
    from OCP.STEPControl import STEPControl_AsIs
    from OCP.TCollection import TCollection_ExtendedString
    from OCP.TDataStd import TDataStd_Name
    from OCP.TDocStd import TDocStd_Document
    from OCP.TopLoc import TopLoc_Location
    from OCP.XCAFDoc import XCAFDoc_DocumentTool
    from OCP.gp import gp_Ax1, gp_Ax2, gp_Dir, gp_Pnt, gp_Trsf, gp_Vec

    hole = BRepPrimAPI_MakeCylinder(gp_Ax2(gp_Pnt(15, 15, -1), gp_Dir(0, 0, 1)), 5.0, 12.0).Shape()
    plate = BRepAlgoAPI_Cut(BRepPrimAPI_MakeBox(gp_Pnt(0, 0, 0), 50.0, 30.0, 10.0).Shape(), hole).Shape()
    pin = BRepPrimAPI_MakeCylinder(gp_Ax2(gp_Pnt(15, 15, 0), gp_Dir(0, 0, 1)), 4.0, 30.0).Shape()
    doc = TDocStd_Document(TCollection_ExtendedString("XmlOcaf"))
    tool = XCAFDoc_DocumentTool.ShapeTool_s(doc.Main())
    top = tool.NewShape()
    TDataStd_Name.Set_s(top, TCollection_ExtendedString("bolt assembly"))
    plate_label = tool.AddShape(plate, False)
    TDataStd_Name.Set_s(plate_label, TCollection_ExtendedString("plate"))
    pin_label = tool.AddShape(pin, False)
    TDataStd_Name.Set_s(pin_label, TCollection_ExtendedString("pin"))
    tool.AddComponent(top, plate_label, TopLoc_Location())
    moved = gp_Trsf()
    moved.SetRotation(gp_Ax1(gp_Pnt(25, 15, 0), gp_Dir(0, 0, 1)), 3.141592653589793 / 2)
    shift = gp_Trsf()
    shift.SetTranslation(gp_Vec(0, 0, 10))
    tool.AddComponent(top, plate_label, TopLoc_Location(shift.Multiplied(moved)))
    tool.AddComponent(top, pin_label, TopLoc_Location())
    tool.UpdateAssemblies()
    writer = STEPCAFControl_Writer()
    writer.Transfer(doc, STEPControl_AsIs, None, Message_ProgressRange())
    if writer.Write(str(path)) != IFSelect_RetDone:
        raise RuntimeError("could not write the assembly")
    return Path(path)
