"""The shape-sorter fixture: a block whose top plate has one blind hole per shape, built from boxes.

Sorter frame: origin at the centre of the bottom face, z up; the holes lie in a row along y (in
``LAYOUT_ORDER``, the square in the middle). The block is a base slab (height ``BASE_HEIGHT_M``) under a
plate as thick as the hole depth; the base's top face is every hole's floor, so holes are blind and a
peg rests at depth = hole depth.

Every hole sits in a square opening of half-size a in the plate; the plate around the openings is four
axis-aligned boxes per cell. Inside an opening, each hole edge i owns one wall box whose inner face lies
on the edge's line: it covers the piece W_i of (opening minus hole) between the rays from the hole centre
through the edge's two vertices, W_i = opening ∩ {n_i . p >= d_i} ∩ wedge_i, which is convex. The union of
the W_i is exactly the opening minus the hole, so the walls are exact and closed, and a box never enters
the hole (it lies on the outer side of its own edge). Boxes may stick out of their W_i into solid plate,
but never out of their cell. Contacts with boxes are computed exactly by MuJoCo's box colliders. The
overlapping wall boxes are not drawn; a non-colliding skin of convex prisms over the pieces W_i is.

Chamfer. With ``chamfer_m`` = c > 0 every hole mouth is bevelled at 45 deg: the top c of each wall piece W_i
(edge line n_i . p = d_i) becomes the convex solid
    C_i = {(p, z) : p in W_i, z_top - c <= z <= z_top, z - (z_top - c) <= n_i . p - d_i},
the piece minus the wedge above the plane rising at 45 deg from the edge line at depth c, so the opening at
the top face is the hole offset outwards by c. C_i is the convex hull of the piece's vertices at z_top - c,
each vertex v raised to z_top - c + min(c, n_i . v - d_i), and the top polygon W_i clipped to n_i . p >= d_i + c;
MuJoCo collides it as a convex mesh. The wall boxes then stop at z_top - c. For regular holes the rays between
pieces bisect the corners, so neighbouring bevels meet exactly; at the rectangle's corners (rays not bisecting)
the two bevels meet with a step of up to c (1 - tan 26.6 deg) ~ c/2 on the corner ray.

Site ``hole_<shape>``: centre of the hole's top opening, z up out of the hole, x the hole's reference
heading (the goal peg_tip x axis).
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType
from typing import Mapping

from typing import TYPE_CHECKING

import numpy as np

from envs.cell.contact import ContactConfig
from envs.cell.shapes import SHAPES, hole_polygon, peg_cross_section
from envs.errors import EnvError
from envs.geometry import FloatArray, clip_polygon, edge_lines, polygon_area, rectangle

if TYPE_CHECKING:  # loads MuJoCo: imported where the model is built, so the limits here stay light
    from dm_control import mjcf

LAYOUT_ORDER: tuple[str, ...] = ("triangle", "circle", "square", "rectangle", "hexagon")
"""Hole order along the sorter's +y axis."""

BASE_HEIGHT_M: float = 0.02
OPENING_MARGIN_M: float = 0.004
"""Plate material kept between a hole's farthest corner and its square opening."""
MAX_OVERHANG_M: float = 0.005
"""Largest distance a wall box may stick out of its hole's square opening into the plate."""
MAX_PARTS_PER_EDGE: int = 8
MIN_PIECE_AREA_M2: float = 1e-8
"""Wall pieces smaller than this (0.01 mm^2, never reached by the default shapes) are left out."""
RIM_M: float = 0.01
"""Plate material between the outermost wall box and the cell border."""
COLLISION_ONLY_GROUP: int = 3
"""Geom group of collision geoms that are not drawn (MuJoCo draws groups 0-2 by default)."""
SORTER_RGBA: tuple[float, float, float, float] = (0.80, 0.65, 0.42, 1.0)
MIN_CLEARANCE_M: float = 1e-4
MAX_CLEARANCE_M: float = 5e-3
MIN_HOLE_DEPTH_M: float = 0.03
MAX_HOLE_DEPTH_M: float = 0.2
MAX_CHAMFER_M: float = 0.003
"""Widest chamfer: it must stay inside every hole's square opening (OPENING_MARGIN_M around the hole)."""


@dataclass(frozen=True)
class WallBox:
    """A box of the sorter plate, in the sorter's horizontal plane.

    Attributes:
        centre_xy: box centre (x, y) m.
        half_size_xy: half extents (along the box x, along the box y) m.
        yaw_rad: rotation of the box x axis from the sorter x axis.
    """

    centre_xy: tuple[float, float]
    half_size_xy: tuple[float, float]
    yaw_rad: float

    def corners(self) -> FloatArray:
        """The four corners (4, 2) in the sorter plane."""
        # here: the task configs import this module, --help must not load numba
        from numerics.small_linalg import matmul

        c, s = np.cos(self.yaw_rad), np.sin(self.yaw_rad)
        hx, hy = self.half_size_xy
        local = np.array([[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy]])
        return matmul(local, np.array([[c, s], [-s, c]])) + np.asarray(self.centre_xy)


@dataclass(frozen=True)
class SorterLayout:
    """Geometry of the sorter in its own frame (all lengths in metres).

    Attributes:
        clearance_m, hole_depth_m: as requested.
        opening_half_m: half-size a of each hole's square opening.
        cell_half_xy: half extents of every hole's cell (x across, y along the row).
        hole_xy: hole centre (x, y) per shape.
        hole_polygons: hole vertices (n, 2) per shape, in the hole frame.
        wall_boxes: the wall boxes per shape, in the sorter frame (they may overlap).
        wall_pieces: per shape, the convex polygons the wall boxes were made for; with the plate boxes
            they tile the plate exactly (no overlap), which the visual skin uses.
        wall_edges: per shape and piece, the hole edge line (outward normal n (2,), offset d) it lies on.
        chamfer_m: width c of the 45 deg bevel at every hole mouth (0: sharp edges).
        plate_boxes: the boxes tiling the plate around the openings.
    """

    clearance_m: float
    hole_depth_m: float
    chamfer_m: float
    opening_half_m: Mapping[str, float]
    cell_half_xy: tuple[float, float]
    hole_xy: Mapping[str, tuple[float, float]]
    hole_polygons: Mapping[str, FloatArray]
    wall_boxes: Mapping[str, tuple[WallBox, ...]]
    wall_pieces: Mapping[str, tuple[FloatArray, ...]]
    wall_edges: Mapping[str, tuple[tuple[FloatArray, float], ...]]
    plate_boxes: tuple[WallBox, ...]

    @property
    def size_xy_m(self) -> tuple[float, float]:
        """Outer footprint (x, y) of the sorter."""
        return 2.0 * self.cell_half_xy[0], 2.0 * self.cell_half_xy[1] * len(self.hole_xy)

    @property
    def height_m(self) -> float:
        """Height of the top face above the bottom face."""
        return BASE_HEIGHT_M + self.hole_depth_m

    def hole_position(self, shape: str) -> FloatArray:
        """Position of site ``hole_<shape>`` (centre of the top opening) in the sorter frame."""
        x, y = self.hole_xy[shape]
        return np.array([x, y, self.height_m])


def wedge_piece(
    normal: FloatArray, offset: float, ray_from: FloatArray, ray_to: FloatArray, opening: FloatArray
) -> FloatArray | None:
    """W = opening ∩ {n . p >= d} ∩ {r0 x p >= 0} ∩ {r1 x p <= 0}, or None when it has no area.

    W is the part of the opening outside the edge line (n, d) between the rays from the hole centre
    through r0 and r1; an intersection of convex sets, so convex.
    """
    piece = clip_polygon(opening, -normal, -offset)
    piece = clip_polygon(piece, np.array([ray_from[1], -ray_from[0]]), 0.0)
    piece = clip_polygon(piece, np.array([-ray_to[1], ray_to[0]]), 0.0)
    if len(piece) < 3 or polygon_area(piece) < MIN_PIECE_AREA_M2:
        return None
    return piece


def edge_box(piece: FloatArray, normal: FloatArray, offset: float) -> WallBox:
    """Smallest box aligned with the edge line (n, d) holding ``piece``, its inner face on the line.

    It spans s = n . p - d in [0, max s] and u = t . p in [min u, max u] over the piece's vertices,
    t = (-n_y, n_x).
    """
    from numerics.small_linalg import matvec  # here: the task configs import this module, --help must not load numba

    tangent = np.array([-normal[1], normal[0]])
    s = matvec(piece, normal) - offset
    u = matvec(piece, tangent)
    depth, u_min, u_max = float(np.max(s)), float(np.min(u)), float(np.max(u))
    centre = (offset + depth / 2.0) * normal + (u_min + u_max) / 2.0 * tangent
    return WallBox(
        centre_xy=(float(centre[0]), float(centre[1])),
        half_size_xy=(depth / 2.0, (u_max - u_min) / 2.0),
        yaw_rad=float(np.arctan2(normal[1], normal[0])),
    )


def hole_walls(
    polygon: FloatArray, opening_half_m: float
) -> tuple[tuple[WallBox, ...], tuple[FloatArray, ...], tuple[tuple[FloatArray, float], ...]]:
    """Wall boxes with inner faces on the hole edges filling the square opening [-a, a]^2 around a convex hole.

    Edge i (vertices v_i, v_{i+1}) is split into k equal parts, each owning the ``edge_box`` of its
    ``wedge_piece``; k = 1, 2, ... is raised until no box corner sticks out of the opening by more than
    ``MAX_OVERHANG_M`` (the pieces thin out as k grows, so the boxes hug them). The pieces tile the opening
    minus the hole exactly, so the hole's walls are exact and closed.

    Args:
        polygon: counter-clockwise hole vertices (n, 2) around the origin (which must be inside).
        opening_half_m: half-size a of the square opening; the hole must fit inside it.

    Returns:
        (boxes, pieces, edges): box j holds piece j (convex polygons (m, 2)), which lies on the outer side of
        edge line j (n, d); boxes may overlap, pieces do not.
    """
    normals, offsets = edge_lines(polygon)
    opening = rectangle(-opening_half_m, opening_half_m, -opening_half_m, opening_half_m)
    boxes: list[WallBox] = []
    pieces: list[FloatArray] = []
    edges: list[tuple[FloatArray, float]] = []
    for i, (normal, offset) in enumerate(zip(normals, offsets)):
        v0, v1 = polygon[i], polygon[(i + 1) % len(polygon)]
        for parts in range(1, MAX_PARTS_PER_EDGE + 1):
            ticks = [v0 + (v1 - v0) * j / parts for j in range(parts + 1)]
            edge_pieces = [wedge_piece(normal, offset, ticks[j], ticks[j + 1], opening) for j in range(parts)]
            edge_pieces = [piece for piece in edge_pieces if piece is not None]
            edge_boxes = [edge_box(piece, normal, offset) for piece in edge_pieces]
            overhang = max((float(np.max(np.abs(b.corners()))) for b in edge_boxes), default=0.0) - opening_half_m
            if overhang <= MAX_OVERHANG_M:
                break
        boxes.extend(edge_boxes)
        pieces.extend(edge_pieces)
        edges.extend((normal.copy(), float(offset)) for _ in edge_pieces)
    return tuple(boxes), tuple(pieces), tuple(edges)


def chamfer_vertices(piece: FloatArray, normal: FloatArray, offset: float, chamfer_m: float, z_top: float) -> FloatArray:
    """Vertices (k, 3) whose convex hull is the bevel solid C of one wall piece (module docstring).

    Raises:
        EnvError: if the bevel would cut the piece down to its outer boundary (chamfer too wide).
    """
    from numerics.small_linalg import matvec  # here: the task configs import this module, --help must not load numba

    z0 = z_top - chamfer_m
    rise = np.minimum(matvec(piece, normal) - offset, chamfer_m)
    top = clip_polygon(piece, -normal, -(offset + chamfer_m))
    if len(top) < 3 or polygon_area(top) < MIN_PIECE_AREA_M2:
        raise EnvError(f"chamfer_m={chamfer_m} is too wide for the hole's opening (a wall piece is cut away)")
    points = np.vstack([
        np.column_stack([piece, np.full(len(piece), z0)]),
        np.column_stack([piece, z0 + rise]),
        np.column_stack([top, np.full(len(top), z_top)]),
    ])
    return np.unique(np.round(points, 12), axis=0)


def cell_plate_boxes(
    hole_xy: tuple[float, float], opening_half_m: float, cell_half_xy: tuple[float, float]
) -> tuple[WallBox, ...]:
    """Four axis-aligned boxes tiling a cell minus its square opening (zero-width ones left out)."""
    (x0, y0), a, (cx, cy) = hole_xy, opening_half_m, cell_half_xy
    candidates = [  # (x_min, x_max, y_min, y_max)
        (a, cx, -cy, cy),
        (-cx, -a, -cy, cy),
        (-a, a, a, cy),
        (-a, a, -cy, -a),
    ]
    boxes = []
    for x_min, x_max, y_min, y_max in candidates:
        if x_max - x_min > 1e-9 and y_max - y_min > 1e-9:
            boxes.append(
                WallBox(
                    centre_xy=(x0 + (x_min + x_max) / 2.0, y0 + (y_min + y_max) / 2.0),
                    half_size_xy=((x_max - x_min) / 2.0, (y_max - y_min) / 2.0),
                    yaw_rad=0.0,
                )
            )
    return tuple(boxes)


def check_clearance(clearance_m: float) -> float:
    """Return ``clearance_m`` if it lies in [MIN_CLEARANCE_M, MAX_CLEARANCE_M].

    Raises:
        EnvError: otherwise.
    """
    if not (np.isfinite(clearance_m) and MIN_CLEARANCE_M <= clearance_m <= MAX_CLEARANCE_M):
        raise EnvError(
            f"clearance_m={clearance_m} is outside [{MIN_CLEARANCE_M * 1e3:g} mm, {MAX_CLEARANCE_M * 1e3:g} mm]"
        )
    return float(clearance_m)


def check_hole_depth(hole_depth_m: float) -> float:
    """Return ``hole_depth_m`` if it lies in [MIN_HOLE_DEPTH_M, MAX_HOLE_DEPTH_M].

    Raises:
        EnvError: otherwise.
    """
    if not (np.isfinite(hole_depth_m) and MIN_HOLE_DEPTH_M <= hole_depth_m <= MAX_HOLE_DEPTH_M):
        raise EnvError(f"hole_depth_m={hole_depth_m} is outside [{MIN_HOLE_DEPTH_M}, {MAX_HOLE_DEPTH_M}] m")
    return float(hole_depth_m)


def check_chamfer(chamfer_m: float) -> float:
    """Return ``chamfer_m`` if it lies in [0, MAX_CHAMFER_M].

    Raises:
        EnvError: otherwise.
    """
    if not (np.isfinite(chamfer_m) and 0.0 <= chamfer_m <= MAX_CHAMFER_M):
        raise EnvError(f"chamfer_m={chamfer_m} is outside [0, {MAX_CHAMFER_M * 1e3:g} mm]")
    return float(chamfer_m)


def sorter_layout(clearance_m: float, hole_depth_m: float, chamfer_m: float = 0.0) -> SorterLayout:
    """Lay the holes of every shape out in a row and tile the plate (a pure function of its inputs).

    Each hole's opening half-size is a = its circumradius + OPENING_MARGIN_M; the cell half-size is the
    farthest wall-box corner (or the largest a) plus RIM_M, the same for every cell, and cell k of n is
    centred at y_k = (2k - n + 1) cy.

    Raises:
        EnvError: if the clearance or the depth is out of range.
    """
    from numerics.small_linalg import dot  # here: the task configs import this module, --help must not load numba

    check_clearance(clearance_m)
    check_hole_depth(hole_depth_m)
    check_chamfer(chamfer_m)
    if chamfer_m >= hole_depth_m:
        raise EnvError(f"chamfer_m={chamfer_m} must be smaller than hole_depth_m={hole_depth_m}")
    polygons = {shape: hole_polygon(shape, clearance_m) for shape in SHAPES}
    opening_half = {s: float(np.max(np.linalg.norm(p, axis=1))) + OPENING_MARGIN_M for s, p in polygons.items()}
    walls = {shape: hole_walls(polygons[shape], opening_half[shape]) for shape in SHAPES}
    corners = np.vstack([box.corners() for boxes, _, _ in walls.values() for box in boxes])
    cell_half = (
        max(max(opening_half.values()), float(np.max(np.abs(corners[:, 0])))) + RIM_M,
        max(max(opening_half.values()), float(np.max(np.abs(corners[:, 1])))) + RIM_M,
    )
    n = len(LAYOUT_ORDER)
    hole_xy = {shape: (0.0, (2 * k - n + 1) * cell_half[1]) for k, shape in enumerate(LAYOUT_ORDER)}
    wall_boxes = {
        shape: tuple(
            WallBox((b.centre_xy[0] + hole_xy[shape][0], b.centre_xy[1] + hole_xy[shape][1]), b.half_size_xy, b.yaw_rad)
            for b in walls[shape][0]
        )
        for shape in LAYOUT_ORDER
    }
    wall_pieces = {shape: tuple(p + np.asarray(hole_xy[shape]) for p in walls[shape][1]) for shape in LAYOUT_ORDER}
    wall_edges = {  # edge lines moved with their hole: d' = d + n . c_hole
        shape: tuple((n, d + dot(n, np.asarray(hole_xy[shape]))) for n, d in walls[shape][2]) for shape in LAYOUT_ORDER
    }
    plate = tuple(
        box for shape in LAYOUT_ORDER for box in cell_plate_boxes(hole_xy[shape], opening_half[shape], cell_half)
    )
    return SorterLayout(
        clearance_m=float(clearance_m),
        hole_depth_m=float(hole_depth_m),
        chamfer_m=float(chamfer_m),
        opening_half_m=MappingProxyType({s: opening_half[s] for s in LAYOUT_ORDER}),
        cell_half_xy=cell_half,
        hole_xy=MappingProxyType(hole_xy),
        hole_polygons=MappingProxyType({s: polygons[s] for s in LAYOUT_ORDER}),
        wall_boxes=MappingProxyType(wall_boxes),
        wall_pieces=MappingProxyType(wall_pieces),
        wall_edges=MappingProxyType(wall_edges),
        plate_boxes=plate,
    )


def build_sorter(layout: SorterLayout, contact: ContactConfig) -> mjcf.RootElement:
    """MJCF model "sorter" of ``layout``: base slab, plate and wall boxes, and one ``hole_<shape>`` site each.

    Collision geoms (with ``contact``'s settings): boxes ``base``, ``plate_<k>`` and ``wall_<shape>_<i>``, and
    with a chamfer the convex meshes ``chamfer_<shape>_<i>`` on top of the walls (drawn).
    The wall boxes overlap one another and the plate (coplanar top faces, which render with shadow acne),
    so they sit in geom group 3 (hidden by default) and the visible top around each hole is a skin of
    non-colliding convex prisms ``skin_<shape>_<i>``, one per wall piece, which with the plate boxes tile
    the plate without overlap.
    """
    from dm_control import mjcf

    sorter = mjcf.RootElement(model="sorter")
    # priority 1 over the peg's 0: a peg-sorter contact takes the sorter's friction (MuJoCo: the higher-priority
    # geom's parameters), so an episode's hole friction is set on the sorter alone (envs.sim.friction)
    attributes = dict(contact.geom_attributes(), rgba=SORTER_RGBA, priority=1)
    size_x, size_y = layout.size_xy_m
    sorter.worldbody.add(
        "geom", name="base", type="box", size=[size_x / 2.0, size_y / 2.0, BASE_HEIGHT_M / 2.0],
        pos=[0.0, 0.0, BASE_HEIGHT_M / 2.0], **attributes,
    )
    chamfer = layout.chamfer_m

    def add_box(name: str, box: WallBox, group: int, top: float) -> None:
        half_height = (top - BASE_HEIGHT_M) / 2.0
        sorter.worldbody.add(
            "geom", name=name, type="box", size=[box.half_size_xy[0], box.half_size_xy[1], half_height],
            pos=[box.centre_xy[0], box.centre_xy[1], BASE_HEIGHT_M + half_height],
            quat=[np.cos(box.yaw_rad / 2.0), 0.0, 0.0, np.sin(box.yaw_rad / 2.0)], group=group, **attributes,
        )

    for k, box in enumerate(layout.plate_boxes):
        add_box(f"plate_{k}", box, group=0, top=layout.height_m)
    for shape in LAYOUT_ORDER:
        for i, box in enumerate(layout.wall_boxes[shape]):
            add_box(f"wall_{shape}_{i}", box, group=COLLISION_ONLY_GROUP, top=layout.height_m - chamfer)
        if chamfer > 0.0:
            for i, (piece, (normal, offset)) in enumerate(zip(layout.wall_pieces[shape], layout.wall_edges[shape])):
                vertices = chamfer_vertices(piece, normal, offset, chamfer, layout.height_m)
                sorter.asset.add("mesh", name=f"chamfer_{shape}_{i}", vertex=vertices.reshape(-1))
                sorter.worldbody.add("geom", name=f"chamfer_{shape}_{i}", type="mesh", mesh=f"chamfer_{shape}_{i}",
                                     group=0, **attributes)
        for i, piece in enumerate(layout.wall_pieces[shape]):
            vertices = np.vstack([
                np.column_stack([piece, np.full(len(piece), BASE_HEIGHT_M)]),
                np.column_stack([piece, np.full(len(piece), layout.height_m - chamfer)]),
            ])
            sorter.asset.add("mesh", name=f"skin_{shape}_{i}", vertex=vertices.reshape(-1))
            sorter.worldbody.add(
                "geom", name=f"skin_{shape}_{i}", type="mesh", mesh=f"skin_{shape}_{i}", contype=0, conaffinity=0,
                group=0, mass=0.0, rgba=SORTER_RGBA,
            )
        sorter.worldbody.add(
            "site", name=f"hole_{shape}", pos=layout.hole_position(shape), size=[0.004], rgba=[0, 1, 1, 1], group=4
        )
    return sorter


def symmetry_order(shape: str) -> int:
    """Rotational symmetry order of ``shape`` about the hole axis (0: round)."""
    return peg_cross_section(shape).symmetry_order
