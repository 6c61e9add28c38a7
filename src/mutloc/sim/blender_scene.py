"""Builds and renders a scene spec (:func:`mutloc.sim.blender.scene_spec`) in Blender's Cycles.

Runs in an interpreter that has the ``bpy`` wheel (``python blender_scene.py
SPEC.json``): it imports nothing of mutloc, only ``bpy``, ``json`` and
``math``, so it can run in a virtual environment of its own (``bpy`` 5.0
pins ``numpy<2``, which the rest of mutloc's dependencies no longer
accept).  Every image named in the spec's ``views`` is written as an 8-bit
sRGB PNG ("Standard" view transform: the file holds sRGB-encoded linear
radiance, as mutloc's own renderer writes it).

Geometry is the spec's, unchanged: spheres as fine UV spheres (silhouette
within 0.1 % of the radius), capped cylinders, boxes, textured quads.
Materials: matte (diffuse) or glossy plastic balls (Principled BSDF, low
roughness, white highlight), metal mounts, emissive lights.  The key light
is a point (or small sphere) light placed and tinted as the spec's light;
the spec's ambient term becomes a soft area light under the ceiling; all
the rest (bounces off walls and floor, soft shadows, highlights,
reflections of the room in glossy surfaces) is Cycles' path tracing.
"""

from __future__ import annotations

import json
import math
import sys
import time


def _mat_diffuse(bpy, name, rgb, roughness=1.0, specular=0.0, metallic=0.0, emission=None):
    m = bpy.data.materials.new(name)
    m.use_nodes = True
    nt = m.node_tree
    bsdf = nt.nodes.get("Principled BSDF")
    bsdf.inputs["Base Color"].default_value = (rgb[0], rgb[1], rgb[2], 1.0)
    bsdf.inputs["Roughness"].default_value = float(roughness)
    bsdf.inputs["Metallic"].default_value = float(metallic)
    bsdf.inputs["Specular IOR Level"].default_value = float(specular)
    if emission is not None:
        bsdf.inputs["Emission Color"].default_value = (emission[0], emission[1], emission[2], 1.0)
        bsdf.inputs["Emission Strength"].default_value = 1.0
    return m


def _mat_texture(bpy, name, path, tint, interpolation="Linear"):
    m = bpy.data.materials.new(name)
    m.use_nodes = True
    nt = m.node_tree
    bsdf = nt.nodes.get("Principled BSDF")
    bsdf.inputs["Roughness"].default_value = 0.9
    bsdf.inputs["Specular IOR Level"].default_value = 0.2
    tex = nt.nodes.new("ShaderNodeTexImage")
    tex.image = bpy.data.images.load(path, check_existing=True)
    tex.extension = "EXTEND"
    tex.interpolation = interpolation
    mix = nt.nodes.new("ShaderNodeMix")
    mix.data_type = "RGBA"
    mix.blend_type = "MULTIPLY"
    mix.inputs["Factor"].default_value = 1.0
    nt.links.new(tex.outputs["Color"], mix.inputs[6])
    mix.inputs[7].default_value = (tint[0], tint[1], tint[2], 1.0)
    nt.links.new(mix.outputs[2], bsdf.inputs["Base Color"])
    return m


def _link(bpy, name, mesh, mat):
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    if mat is not None:
        mesh.materials.append(mat)
    return obj


def _sphere(bpy, name, c, r, mat, segments=128, rings=64):
    verts = [(c[0], c[1], c[2] + r), (c[0], c[1], c[2] - r)]
    for i in range(1, rings):
        th = math.pi * i / rings
        z, s = r * math.cos(th), r * math.sin(th)
        for j in range(segments):
            ph = 2 * math.pi * j / segments
            verts.append((c[0] + s * math.cos(ph), c[1] + s * math.sin(ph), c[2] + z))
    faces = []
    idx = lambda i, j: 2 + (i - 1) * segments + (j % segments)  # noqa: E731
    for j in range(segments):
        faces.append((0, idx(1, j), idx(1, j + 1)))
        faces.append((1, idx(rings - 1, j + 1), idx(rings - 1, j)))
    for i in range(1, rings - 1):
        for j in range(segments):
            faces.append((idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1)))
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts, [], faces)
    mesh.shade_smooth()
    return _link(bpy, name, mesh, mat)


def _cylinder(bpy, name, c, axis, r, half, mat, segments=96):
    ax = axis
    a = (1.0, 0.0, 0.0) if abs(ax[0]) < 0.9 else (0.0, 1.0, 0.0)
    e1 = _norm(_cross(ax, a))
    e2 = _cross(ax, e1)
    verts = []
    for sgn in (-1.0, 1.0):
        for j in range(segments):
            ph = 2 * math.pi * j / segments
            verts.append(tuple(c[k] + sgn * half * ax[k] + r * (math.cos(ph) * e1[k] + math.sin(ph) * e2[k])
                               for k in range(3)))
    faces = [tuple(range(segments))[::-1], tuple(range(segments, 2 * segments))]
    for j in range(segments):
        faces.append((j, (j + 1) % segments, segments + (j + 1) % segments, segments + j))
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts, [], faces)
    for p in mesh.polygons:
        p.use_smooth = len(p.vertices) == 4
    return _link(bpy, name, mesh, mat)


def _box(bpy, name, c, R, half, mat):
    verts = []
    for sx in (-1, 1):
        for sy in (-1, 1):
            for sz in (-1, 1):
                loc = (sx * half[0], sy * half[1], sz * half[2])
                verts.append(tuple(c[k] + sum(R[k][a] * loc[a] for a in range(3)) for k in range(3)))
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts, [], faces)
    return _link(bpy, name, mesh, mat)


def _quad(bpy, name, c, u, v, hu, hv, mat, uv_scale=(1.0, 1.0)):
    verts = [tuple(c[k] + su * hu * u[k] + sv * hv * v[k] for k in range(3))
             for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts, [], [(0, 1, 2, 3)])
    layer = mesh.uv_layers.new(name="UVMap")
    fu, fv = uv_scale
    # The texture's left column is the quad's -u edge and its top row the +v edge (Blender's v = 1).
    for li, uv in enumerate(((0.0, 1.0 - fv), (fu, 1.0 - fv), (fu, 1.0), (0.0, 1.0))):
        layer.data[li].uv = uv
    return _link(bpy, name, mesh, mat)


def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _norm(a):
    n = math.sqrt(sum(x * x for x in a))
    return tuple(x / n for x in a)


def build(bpy, spec):
    """The spec's scene in a fresh Blender file."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    sc.cycles.device = "CPU"
    r = spec["render"]
    sc.cycles.samples = int(r["samples"])
    sc.cycles.use_adaptive_sampling = True
    sc.cycles.use_denoising = bool(r.get("denoise", True))
    sc.cycles.max_bounces = int(r.get("bounces", 4))
    sc.cycles.diffuse_bounces = min(int(r.get("bounces", 4)), 2)
    sc.cycles.glossy_bounces = min(int(r.get("bounces", 4)), 2)
    sc.cycles.transmission_bounces = sc.cycles.volume_bounces = sc.cycles.transparent_max_bounces = 0
    sc.cycles.caustics_reflective = sc.cycles.caustics_refractive = False
    sc.cycles.seed = int(r.get("seed", 0))
    sc.cycles.blur_glossy = 1.0
    sc.cycles.sample_clamp_indirect = 10.0
    sc.render.threads_mode = "FIXED"
    sc.render.threads = int(r.get("threads", 2))
    sc.view_settings.view_transform = "Standard"
    sc.view_settings.look = "None"
    sc.view_settings.exposure = float(r.get("exposure_stops", 0.0))
    sc.render.image_settings.file_format = "PNG"
    sc.render.image_settings.color_depth = "8"
    sc.render.image_settings.color_mode = "RGB"
    if r.get("glare"):
        _glare(bpy, sc, r["glare"])
    world = bpy.data.worlds.new("world")
    world.use_nodes = True
    bg = world.node_tree.nodes.get("Background")
    b = spec.get("background", [0.0, 0.0, 0.0])
    bg.inputs["Color"].default_value = (b[0], b[1], b[2], 1.0)
    sc.world = world

    mats = {}

    def material(key, make):
        if key not in mats:
            mats[key] = make()
        return mats[key]

    for k, p in enumerate(spec["objects"]):
        kind = p["kind"]
        name = f"{k:03d}_{p.get('name', kind)}"
        fin = p.get("finish", "matte")
        col = p.get("color", [0.5, 0.5, 0.5])
        if "texture" in p:
            mat = material(("tex", p["texture"], tuple(p["color"])), lambda p=p: _mat_texture(
                bpy, p["texture"], p["texture"], p["color"], p.get("interpolation", "Linear")))
        elif fin == "emissive":
            mat = material(("em", tuple(p["emission"])),
                           lambda p=p: _mat_diffuse(bpy, "emit", [0, 0, 0], emission=p["emission"]))
        elif fin == "plastic":
            mat = material(("pl", tuple(col)), lambda col=col: _mat_diffuse(bpy, "plastic", col, roughness=0.12,
                                                                              specular=0.5))
        elif fin == "metal":
            mat = material(("me", tuple(col)), lambda col=col: _mat_diffuse(bpy, "metal", col, roughness=0.08,
                                                                             metallic=1.0, specular=0.5))
        else:
            mat = material(("ma", tuple(col)), lambda col=col: _mat_diffuse(bpy, "matte", col))
        if kind == "sphere":
            _sphere(bpy, name, p["centre"], p["radius"], mat)
        elif kind == "cylinder":
            _cylinder(bpy, name, p["centre"], _norm(p["axis"]), p["radius"], p["half_length"], mat)
        elif kind == "box":
            _box(bpy, name, p["centre"], p["R"], p["half"], mat)
        elif kind == "quad":
            _quad(bpy, name, p["centre"], p["u"], p["v"], p["half_u"], p["half_v"], mat,
                  tuple(p.get("uv_scale", (1.0, 1.0))))
        else:
            raise SystemExit(f"unknown object kind {kind!r}")

    li = spec["light"]
    ld = bpy.data.lights.new("key", "POINT")
    ld.energy = float(li["power_w"])
    ld.color = tuple(li["color"])
    ld.shadow_soft_size = float(li["radius"])
    lo = bpy.data.objects.new("key", ld)
    lo.location = tuple(li["position"])
    sc.collection.objects.link(lo)
    fill = spec.get("fill")
    if fill and fill["power_w"] > 0:
        fd = bpy.data.lights.new("fill", "AREA")
        fd.shape = "RECTANGLE"
        fd.size, fd.size_y = float(fill["size"][0]), float(fill["size"][1])
        fd.energy = float(fill["power_w"])
        fd.color = tuple(fill["color"])
        fo = bpy.data.objects.new("fill", fd)
        fo.location = tuple(fill["position"])  # an area light shines along its -z: down
        sc.collection.objects.link(fo)

    cam_data = bpy.data.cameras.new("cam")
    cam = bpy.data.objects.new("cam", cam_data)
    sc.collection.objects.link(cam)
    sc.camera = cam
    return sc, cam


def _glare(bpy, sc, g):
    """The compositor's Bloom on the render: light above ``threshold`` spreads over ``size`` (Blender's Glare node)."""
    tree = bpy.data.node_groups.new("glare", "CompositorNodeTree")
    sc.compositing_node_group = tree
    src = tree.nodes.new("CompositorNodeRLayers")
    glare = tree.nodes.new("CompositorNodeGlare")
    glare.inputs["Type"].default_value = "Bloom"
    glare.inputs["Quality"].default_value = "High"
    glare.inputs["Threshold"].default_value = float(g["threshold"])
    glare.inputs["Size"].default_value = float(g["size"])
    glare.inputs["Strength"].default_value = float(g["strength"])
    out = tree.nodes.new("NodeGroupOutput")
    tree.interface.new_socket("Image", in_out="OUTPUT", socket_type="NodeSocketColor")
    tree.links.new(src.outputs["Image"], glare.inputs["Image"])
    tree.links.new(glare.outputs["Image"], out.inputs[0])
    sc.render.use_compositing = True


def set_view(sc, cam, view):
    """Camera ``view``: OpenCV intrinsics (pinhole, or the equidistant fisheye ``r = f * theta`` centred on
    the image) and camera -> world pose (optical frame)."""
    W, H = (int(x) for x in view["size"])
    K = view["K"]
    sc.render.resolution_x, sc.render.resolution_y = W, H
    sc.render.resolution_percentage = 100
    sc.render.pixel_aspect_x = sc.render.pixel_aspect_y = 1.0
    cd = cam.data
    cd.sensor_fit = "HORIZONTAL"
    cd.sensor_width = 36.0
    lens = view.get("lens", {"model": "pinhole"})
    if lens["model"] == "fisheye":
        # Cycles' fisheyes are centred on the image ((W - 1) / 2, (H - 1) / 2 in OpenCV's pixels) and image the
        # optical frame's x right, y down as OpenCV does (measured: bench/check_blender_fisheye.py).
        f = float(lens["f"])
        cd.type = "PANO"
        cd.shift_x = cd.shift_y = 0.0
        if W == H:
            # The equidistant fisheye's fisheye_fov spans the image's width (and, on a non-square image, its
            # height too: unequal pixel scales), black outside that circle.
            cd.panorama_type = "FISHEYE_EQUIDISTANT"
            cd.fisheye_fov = W / f
        else:
            # theta = -(k0 + k1 r + ...) with r in mm on the sensor (sensor_width over W pixels, square pixels).
            cd.panorama_type = "FISHEYE_LENS_POLYNOMIAL"
            cd.fisheye_fov = 2.0 * math.pi
            cd.fisheye_polynomial_k0 = 0.0
            cd.fisheye_polynomial_k1 = -1.0 / (f * 36.0 / W)
            cd.fisheye_polynomial_k2 = cd.fisheye_polynomial_k3 = cd.fisheye_polynomial_k4 = 0.0
    else:
        cd.type = "PERSP"
        cd.lens = K[0][0] * 36.0 / W
        # Blender's image centre is OpenCV's ((W - 1) / 2, (H - 1) / 2); shifts are in units of the larger side.
        cd.shift_x = ((W - 1) / 2.0 - K[0][2]) / max(W, H)
        cd.shift_y = (K[1][2] - (H - 1) / 2.0) / max(W, H)
    cd.clip_start = 0.01
    cd.clip_end = 100.0
    R, t = view["R"], view["t"]
    # Blender's camera looks along its -z with y up: columns x, -y, -z of the optical frame.
    M = [[R[i][0], -R[i][1], -R[i][2], t[i]] for i in range(3)] + [[0.0, 0.0, 0.0, 1.0]]
    import mathutils

    cam.matrix_world = mathutils.Matrix(M)


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print("usage: python blender_scene.py SPEC.json", file=sys.stderr)
        return 2
    import bpy

    with open(argv[0]) as fh:
        spec = json.load(fh)
    sc, cam = build(bpy, spec)
    for view in spec["views"]:
        set_view(sc, cam, view)
        sc.render.filepath = view["out"]
        t0 = time.time()
        bpy.ops.render.render(write_still=True)
        print(f"rendered {view['out']} in {time.time() - t0:.1f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
