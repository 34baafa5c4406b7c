"""Writes the foreign mesh fixtures next to this script with meshio and VTK.

The tetrahedral mesh is a cube of side 1/32 at (1/8, -1/4, 1/2), split into twelve
tetrahedra around its centre: six with physical tag 11 (volume entity 1), a boundary
triangle pair with physical tag 7 (surface entity 5), six with physical tag 12 (volume
entity 2). All coordinates are dyadic, so every format, ASCII included, stores them
exactly. A float cell array comes first, so readers must pass over it to reach the
integer region array.

    python3 -m venv /tmp/meshio-venv
    /tmp/meshio-venv/bin/pip install meshio numpy vtk
    /tmp/meshio-venv/bin/python make_foreign.py
"""

import os

import meshio
import numpy as np
import vtk

HERE = os.path.dirname(os.path.abspath(__file__))
SIDE = 1.0 / 32.0
OFFSET = np.array([0.125, -0.25, 0.5])

points = [[(i & 1) * SIDE, ((i >> 1) & 1) * SIDE, ((i >> 2) & 1) * SIDE] for i in range(8)]
points.append([SIDE / 2] * 3)
points = np.array(points) + OFFSET

# Cube faces as corner quads (in cyclic order), each split into two triangles.
faces = [(0, 2, 6, 4), (1, 5, 7, 3), (0, 4, 5, 1), (2, 3, 7, 6), (0, 1, 3, 2), (4, 6, 7, 5)]
tets = []
for a, b, c, d in faces:
    for tri in ((a, b, c), (a, c, d)):
        tet = [*tri, 8]
        p = points[tet]
        if np.linalg.det(np.array([p[1] - p[0], p[2] - p[0], p[3] - p[0]])) < 0:
            tet[2], tet[3] = tet[3], tet[2]
        tets.append(tet)
tets = np.array(tets)
triangles = np.array([[0, 2, 6], [0, 6, 4]])

cells = [("tetra", tets[:6]), ("triangle", triangles), ("tetra", tets[6:])]
mesh = meshio.Mesh(
    points,
    cells,
    cell_data={
        "quality": [np.full(6, 0.5), np.full(2, 0.25), np.full(6, 0.75)],
        "gmsh:physical": [np.full(6, 11, np.int32), np.full(2, 7, np.int32), np.full(6, 12, np.int32)],
        "gmsh:geometrical": [np.full(6, 1, np.int32), np.full(2, 5, np.int32), np.full(6, 2, np.int32)],
    },
    # Node entities in index order, so that Gmsh's node blocks keep the points' order:
    # np.unique sorts (2, 5) < (3, 1) < (3, 2).
    point_data={"gmsh:dim_tags": np.array([[2, 5]] * 2 + [[3, 1]] * 4 + [[3, 2]] * 3)},
)


def out(name):
    return os.path.join(HERE, name)


gmsh_mesh = meshio.Mesh(mesh.points, mesh.cells, cell_data=mesh.cell_data, point_data=mesh.point_data)
meshio.write(out("meshio_binary.msh"), gmsh_mesh, file_format="gmsh", binary=True)
meshio.write(out("meshio_ascii.msh"), gmsh_mesh, file_format="gmsh", binary=False)

# The VTK formats have no use for the Gmsh node entities.
vtk_mesh = meshio.Mesh(mesh.points, mesh.cells, cell_data=mesh.cell_data)
meshio.write(out("meshio_ascii.vtu"), vtk_mesh, binary=False)
meshio.write(out("meshio_zlib.vtu"), vtk_mesh)  # meshio's default: base64, zlib
meshio.write(out("meshio_uint64.vtu"), vtk_mesh, compression=None, header_type="UInt64")
meshio.vtk.write(out("meshio_51_binary.vtk"), vtk_mesh, fmt_version="5.1", binary=True)
meshio.vtk.write(out("meshio_42_binary.vtk"), vtk_mesh, fmt_version="4.2", binary=True)

# VTK itself, from meshio's ASCII file: appended raw data (meshio cannot write it),
# appended base64, and its legacy binary writer.
reader = vtk.vtkXMLUnstructuredGridReader()
reader.SetFileName(out("meshio_ascii.vtu"))
reader.Update()
grid = reader.GetOutput()


def xml(name, mode, encode, compressor, header64, big_endian=False):
    w = vtk.vtkXMLUnstructuredGridWriter()
    w.SetFileName(out(name))
    w.SetInputData(grid)
    {"appended": w.SetDataModeToAppended, "binary": w.SetDataModeToBinary}[mode]()
    w.SetEncodeAppendedData(encode)
    if compressor:
        w.SetCompressorTypeToZLib()
    else:
        w.SetCompressorTypeToNone()
    if header64:
        w.SetHeaderTypeToUInt64()
    else:
        w.SetHeaderTypeToUInt32()
    if big_endian:
        w.SetByteOrderToBigEndian()
    assert w.Write() == 1, name


xml("vtk_appended_raw.vtu", "appended", False, False, False)
xml("vtk_appended_raw_zlib64.vtu", "appended", False, True, True)
xml("vtk_appended_base64_zlib.vtu", "appended", True, True, False)
xml("vtk_binary_bigendian.vtu", "binary", False, False, True, big_endian=True)

legacy = vtk.vtkUnstructuredGridWriter()
legacy.SetFileName(out("vtk_binary.vtk"))
legacy.SetInputData(grid)
legacy.SetFileTypeToBinary()
assert legacy.Write() == 1

with open(os.path.join(HERE, "VERSIONS"), "w") as f:
    f.write(f"meshio {meshio.__version__}\nvtk {vtk.vtkVersion.GetVTKVersion()}\n")
    f.write(f"numpy {np.__version__}\n")

print("tets:", tets.tolist())
print("points:", points.tolist())
