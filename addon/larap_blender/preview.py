# SPDX-License-Identifier: GPL-3.0-or-later
"""The GPU preview: while the artist poses, the posed mesh is drawn from the lattice, not written.

Writing a 1M-vertex mesh and re-evaluating it costs Blender hundreds of milliseconds per move;
the lattice is 10k-40k nodes. So while a drag, a live move of a target or a playback goes on,
the add-on poses only the lattice (``solving.solve(lattice_only=True)``) and this module draws
the mesh from it in a vertex shader:

* uploaded once per binding: per vertex its rest position, rest normal, lattice cell and position
  in the cell (``Deformer.trilinear_binding``); per cell its 8 corner nodes (``cell_nodes``);
  Blender's own triangles (``loop_triangles``);
* uploaded per pose: the node displacements (N x RGBA32F texture, N = lattice nodes);
* in the shader: the trilinear blend of the cell's corner displacements (the engine's trilinear
  transfer), and the normal carried by the cofactor of the trilinear map's Jacobian (the
  deformation gradient of the cell at that point) applied to the rest normal; lit like Blender's
  Solid mode (the view's studio light, specular, material/object/single colour; flat-shaded
  meshes use the face normal).

While the preview is shown, the object is hidden in its view layer (``hide_set``) so its stale
evaluated mesh is not seen; :func:`stop` shows it again (and restores its selection) when the
mesh data has caught up (catchup.py). The preview is drawn only where the object would be
visible (view-layer collections, Disable in Viewports, local view).

:func:`blocker` says why the preview cannot show an object truthfully; the caller then writes
the mesh instead (background mode, preview off, B-spline interactive weights, modifiers after the
pose key, other shape keys mixed in, display as wire/bounds, no GPU shader, hidden by the
artist, shading the preview does not draw: mixed flat and smooth faces, custom normals, auto
smooth); when it gives one for an object already shown, the depsgraph handler ends the preview
there (handlers.refresh_preview: the mesh catches up). An object the artist hid stays hidden:
the preview never draws it, and :func:`stop` leaves it hidden as it found it. Nothing in it reads
the mesh per move: the faces' shading is read once per change of the mesh (:func:`face_shading`,
told by the depsgraph handler).

Why one file of over 500 lines: it holds one concept, the GPU preview, whose parts share one
contract that must change together: the texture layouts ``_GpuMesh`` uploads are the ones the
vertex shader reads, the uniform block ``_view_block`` packs is the ``LarapView`` struct the
shaders declare, and the lighting values fill that block. About 120 of the lines are the GLSL
itself. Read it in its banners' order: when the preview can show an object (and hiding it),
per-binding data, the shader, lighting like Solid mode, drawing.
"""
import bpy
import numpy as np

from . import scene_index
from .mesh_data import loop_triangles
from .runtime import runtime

# Kept across importlib.reload (F8 / re-enable), so a reload never orphans a callback or leaves
# an object hidden that nothing knows about.
_DRAW_HANDLE = globals().get("_DRAW_HANDLE")
_SHOWN = globals().get("_SHOWN") or {}  # runtime id -> {"select": bool, "hidden": bool}: objects we hid
_GPU = {}  # runtime id -> _GpuMesh
_SHADER = [None, ""]  # compiled shader, error message
_SHADING = {}  # mesh pointer -> [face count, or None once the mesh changed; face_shading()]
TEX_WIDTH = 2048  # texels per row of the lattice and cell textures
# ID property set on an object while we hide it (1, or 2 when it was selected, 3 when it was
# hidden already): an undo step or an autosave taken meanwhile stores the hidden state with it,
# and reset_all() undoes it.
HIDDEN_PROP = "_larap_preview_hidden"


# ----------------------------------------------------------------------------------------------
# When the preview can show an object

def available():
    """A GPU context exists (never in background mode)."""
    return not bpy.app.background


def blocker(obj):
    """Why the preview cannot draw ``obj`` as Blender would ("" when it can)."""
    if not available():
        return "background mode"
    s = obj.larap
    if not s.preview:
        return "preview off"
    if _SHADER[1]:
        return "GPU preview unavailable: %s" % _SHADER[1]
    if s.weights_interactive != "trilinear":
        return "interactive weights are B-spline (the preview draws trilinear)"
    mods = [m.name for m in obj.modifiers if m.show_viewport]
    if mods:
        return "modifiers after the pose key (%s)" % ", ".join(mods[:3])
    if obj.display_type not in ("SOLID", "TEXTURED"):
        return "object displayed as %s" % obj.display_type.title()
    rt = runtime(obj)
    if rt is not None and rt.loose_edges:
        return "loose edges (the preview draws faces)"
    if not scene_index.in_view_layer(obj, getattr(bpy.context, "view_layer", None)):
        return "not in the current view layer"
    if obj.hide_get() and not showing(obj):
        return "hidden"
    keys = obj.data.shape_keys
    kb = keys.key_blocks.get(s.shape_key) if keys is not None else None
    if kb is None or not keys.use_relative:
        return "no relative pose key"
    if kb.mute or kb.value != 1.0 or kb.vertex_group:
        return "the pose key is not at full strength"
    if obj.show_only_shape_key and obj.active_shape_key != kb:
        return "another shape key is shown alone"
    for other in keys.key_blocks:
        if other != kb and other != keys.reference_key and not other.mute and other.value != 0.0:
            return "other shape keys are mixed in (%s)" % other.name
    return _shading_blocker(obj)


def _shading_blocker(obj):
    """The preview shades a mesh all smooth (its vertex normals) or all flat: say so where Blender
    would shade it otherwise. The faces' flags come from :func:`face_shading` (read once per
    change of the mesh, not per move); the mesh-wide settings are read here (O(1))."""
    me = obj.data
    if getattr(me, "has_custom_normals", False):
        return "custom normals"
    shading = face_shading(obj)
    if shading == "flat":
        return ""
    if shading == "mixed":
        return "mixed flat and smooth faces"
    if getattr(me, "use_auto_smooth", False):  # Blender < 4.1: split normals at sharp edges
        return "auto smooth"
    return ""


def _read_face_shading(me):
    """"smooth", "flat" or "mixed": every face's smooth flag, read (one pass over the faces)."""
    smooth = np.empty(len(me.polygons), dtype=bool)
    me.polygons.foreach_get("use_smooth", smooth)
    if not smooth.any():
        return "flat"
    return "smooth" if smooth.all() else "mixed"


def face_shading(obj):
    """"smooth", "flat" or "mixed": the shading of ``obj``'s faces. Reading a million faces' flags
    costs tens of milliseconds, so it is read once and kept (``_SHADING``) until the mesh changes:
    :func:`meshes_changed` (every depsgraph update of the mesh: Shade Smooth/Flat, leaving Edit
    Mode, a script's update, the catch-up's own write), :func:`reset_all` (undo, redo, load), or
    another face count (another mesh on the object has an entry of its own). A live move changes
    no mesh, so it reads nothing.

    Kept per mesh, not per object: the answer is the mesh's alone. Objects that share one mesh
    (Alt+D) share its one answer; a duplicate with its own mesh (Shift+D) has its own, though it
    shares its original's runtime id until it is bound or posed (runtime.claim_key)."""
    me = obj.data
    count = len(me.polygons)
    entry = _SHADING.get(me.as_pointer())
    if entry is None or entry[0] != count:
        entry = _SHADING[me.as_pointer()] = [count, _read_face_shading(me)]
    return entry[1]


def meshes_changed(pointers):
    """The depsgraph reported these meshes (``Mesh.as_pointer()`` of the originals) updated: their
    faces' shading is read again when next asked (the last answer stays for the draw meanwhile).
    A mesh newly given to an object is reported too, so an entry left by a freed mesh whose
    address was reused is not trusted past the first evaluation."""
    for pointer in pointers:
        entry = _SHADING.get(pointer)
        if entry is not None:
            entry[0] = None


def draws_smooth(obj):
    """The shader's normals for ``obj``: its vertex normals (smooth), else its faces' (flat), as
    its mesh's faces' shading was last read (the blocker keeps a mixed mesh from being drawn)."""
    entry = _SHADING.get(obj.data.as_pointer())
    return entry is None or entry[1] != "flat"


def shading_stale(obj):
    """``obj``'s faces' shading is to be read again (its mesh changed since the last read)."""
    try:
        entry = _SHADING.get(obj.data.as_pointer())
    except ReferenceError:
        return False
    return entry is None or entry[0] is None


def showing(obj):
    try:
        return obj.larap.runtime_id in _SHOWN
    except ReferenceError:
        return False


def shown_keys():
    return set(_SHOWN)


def _tag_redraw():
    wm = getattr(bpy.context, "window_manager", None)
    for win in (wm.windows if wm is not None else ()):
        for area in win.screen.areas:
            if area.type == "VIEW_3D":
                area.tag_redraw()


def show(obj):
    """Draw ``obj`` from its runtime's lattice (rt.lattice_nodes) instead of its mesh. Returns
    False when the object cannot be hidden in the view layer, or there is no posed lattice to
    draw (then write the mesh instead).
    Builds the per-binding data first (:func:`prepare`), here on the live/drag path: the draw
    callback only uploads it and never reads or writes the mesh."""
    rt = runtime(obj)
    if rt is None or rt.lattice_nodes is None:  # nothing posed to draw: never hide the mesh for nothing
        return False
    if rt.loose_edges:  # known only once the runtime is validated (the blocker may have run first)
        return False
    prepare(obj)
    key = obj.larap.runtime_id
    if key in _SHOWN:
        _tag_redraw()
        return True
    try:
        selected = obj.select_get()
        hidden = obj.hide_get()
        obj.hide_set(True)
    except RuntimeError:  # not in the current view layer
        return False
    _SHOWN[key] = {"select": selected, "hidden": hidden}
    obj[HIDDEN_PROP] = 3 if hidden else 2 if selected else 1
    _tag_redraw()
    return True


def stop(obj):
    """Blender draws ``obj`` again (its mesh holds the pose): unhide it, restore its selection."""
    try:
        key = obj.larap.runtime_id
    except ReferenceError:
        return
    entry = _SHOWN.pop(key, None)
    if entry is None:
        return
    _unhide(obj, entry["select"], entry.get("hidden", False))
    _tag_redraw()


def _unhide(obj, selected, hidden=False):
    """Put back the object's own hiding and selection as :func:`show` found them."""
    try:
        if HIDDEN_PROP in obj:
            del obj[HIDDEN_PROP]
        obj.hide_set(hidden)
        if selected and not hidden:
            obj.select_set(True)
    except (RuntimeError, ReferenceError):
        pass


def reset_all():
    """After an undo, a redo or a file load: no preview runs; every object stored hidden behind
    a preview (its ID property says so) is shown again, with its selection."""
    _SHOWN.clear()
    _SHADING.clear()  # the restored meshes may be shaded otherwise
    for obj in bpy.data.objects:
        try:
            mark = obj.get(HIDDEN_PROP)
        except ReferenceError:
            continue
        if mark is not None:
            _unhide(obj, mark == 2, mark == 3)


def forget(key):
    """Drop what we hold for a runtime id whose object is gone."""
    _SHOWN.pop(key, None)
    _GPU.pop(key, None)
    alive = {me.as_pointer() for me in bpy.data.meshes}
    for pointer in [p for p in _SHADING if p not in alive]:  # meshes removed since
        del _SHADING[pointer]


# ----------------------------------------------------------------------------------------------
# Per-binding data (numpy, built by show() outside the draw callback; GPU buffers at the first draw)

def _vertex_normals(co, tris):
    """Angle-weighted vertex normals (n,3) float32 of the triangles ``tris`` over ``co``."""
    p = co.astype(np.float64)
    a, b, c = p[tris[:, 0]], p[tris[:, 1]], p[tris[:, 2]]
    fn = np.cross(b - a, c - a)
    fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-30)
    n = len(co)
    acc = np.zeros((n, 3))
    for k, (u, v) in enumerate(((b - a, c - a), (c - b, a - b), (a - c, b - c))):
        cos = np.einsum("ij,ij->i", u, v) / np.maximum(np.linalg.norm(u, axis=1) * np.linalg.norm(v, axis=1), 1e-30)
        w = np.arccos(np.clip(cos, -1.0, 1.0))
        for j in range(3):
            acc[:, j] += np.bincount(tris[:, k], weights=fn[:, j] * w, minlength=n)
    acc /= np.maximum(np.linalg.norm(acc, axis=1, keepdims=True), 1e-30)
    return acc.astype(np.float32)


def _texture_data(values, width=TEX_WIDTH):
    """(k,4) float32 rows padded to a width x height RGBA32F texture: (size, flat float32)."""
    k = max(len(values), 1)
    height = (k + width - 1) // width
    buf = np.zeros((width * height, 4), dtype=np.float32)
    buf[:len(values)] = values
    return (width, height), buf.reshape(-1)


def _texture(size, flat):
    import gpu
    return gpu.types.GPUTexture(size, format="RGBA32F", data=gpu.types.Buffer("FLOAT", len(flat), flat))


class _GpuMesh:
    """What the shader needs for one binding, built from the engine and the mesh."""

    def __init__(self, obj, rt):
        d = rt.deformer
        me = obj.data
        self.deformer = d
        self.counts = rt.counts
        cells = np.asarray(d.cell_nodes(), dtype=np.float32).reshape(-1, 4)  # 2 texels per cell
        cid, frac = d.trilinear_binding()
        self.rest_nodes = np.asarray(d.lattice_rest(), dtype=np.float32)
        self.cell_size = float(d.cell_size)
        tris = loop_triangles(me)  # 50 ms at 2M triangles (into int32: 210 ms; mesh_data._get_ids)
        self.arrays = {"rest": np.ascontiguousarray(rt.rest, dtype=np.float32),
                       "nrm": _vertex_normals(rt.rest, tris),
                       "cell": np.asarray(cid, dtype=np.float32),
                       "frac": np.ascontiguousarray(frac, dtype=np.float32)}
        self.tris = tris
        self.cells = cells
        self.batch = self.cells_tex = self.nodes_tex = None
        self.version = None

    def upload(self, shader):
        import gpu
        fmt = gpu.types.GPUVertFormat()
        for name, width in (("rest", 3), ("nrm", 3), ("cell", 1), ("frac", 3)):
            fmt.attr_add(id=name, comp_type="F32", len=width, fetch_mode="FLOAT")
        vbo = gpu.types.GPUVertBuf(fmt, len(self.arrays["rest"]))
        for name, values in self.arrays.items():
            vbo.attr_fill(name, values)
        ibo = gpu.types.GPUIndexBuf(type="TRIS", seq=self.tris)
        self.batch = gpu.types.GPUBatch(type="TRIS", buf=vbo, elem=ibo)
        self.cells_tex = _texture(*_texture_data(self.cells))
        self.arrays = self.tris = self.cells = None  # on the GPU now

    def set_pose(self, nodes, version):
        disp = np.zeros((len(self.rest_nodes), 4), dtype=np.float32)
        disp[:, :3] = nodes - self.rest_nodes
        self.nodes_tex = _texture(*_texture_data(disp))
        self.version = version


def _gpu_mesh(obj, rt):
    key = obj.larap.runtime_id
    g = _GPU.get(key)
    if g is None or g.deformer is not rt.deformer or g.counts != rt.counts:
        g = _GPU[key] = _GpuMesh(obj, rt)
    return g


def prepare(obj):
    """Build the per-binding arrays now (outside a draw callback)."""
    rt = runtime(obj)
    if rt is not None and rt.deformer is not None:
        _gpu_mesh(obj, rt)


# ----------------------------------------------------------------------------------------------
# The shader (GPUShaderCreateInfo: Blender 3.4+, and the only way on 4.x's Metal/Vulkan backends)

# Per view and object (a uniform block: the push constants stay within the 128 bytes that
# Metal and Vulkan guarantee). vec4/mat4 members only, so the std140 layout is the packed one.
_TYPEDEFS = """
struct LarapView {
  mat4 model_view;
  mat4 normal_matrix;
  vec4 base_color;
  vec4 material;  /* roughness, metallic, specular on, unlit */
  vec4 mode;      /* smooth normals, perspective */
  vec4 ambient;
  vec4 light_dir[4];
  vec4 light_diffuse[4];  /* rgb, wrap */
  vec4 light_specular[4];
};
"""
_VIEW_FIELDS = ("model_view", "normal_matrix", "base_color", "material", "mode", "ambient")

_VERTEX = """
ivec2 texel(int i) { return ivec2(i % tex_width, i / tex_width); }

void main()
{
  int c = int(cell + 0.5);
  vec4 ids_a = texelFetch(cells_tx, texel(2 * c), 0);
  vec4 ids_b = texelFetch(cells_tx, texel(2 * c + 1), 0);
  float ids[8] = float[8](ids_a.x, ids_a.y, ids_a.z, ids_a.w, ids_b.x, ids_b.y, ids_b.z, ids_b.w);
  vec3 disp = vec3(0.0);
  /* Columns of the trilinear map's Jacobian d(position)/d(cell coordinates). */
  vec3 ju = vec3(cell_size, 0.0, 0.0), jv = vec3(0.0, cell_size, 0.0), jw = vec3(0.0, 0.0, cell_size);
  for (int k = 0; k < 8; k++) {
    vec3 d = texelFetch(nodes_tx, texel(int(ids[k] + 0.5)), 0).xyz;
    vec3 s = vec3(float(k & 1), float((k >> 1) & 1), float(k >> 2));
    vec3 f = mix(1.0 - frac, frac, s);  /* per-axis weight factors of corner k */
    vec3 g = 2.0 * s - 1.0;             /* their derivatives */
    disp += (f.x * f.y * f.z) * d;
    ju += (g.x * f.y * f.z) * d;
    jv += (f.x * g.y * f.z) * d;
    jw += (f.x * f.y * g.z) * d;
  }
  vec3 p = rest + disp;
  /* Normals follow the cofactor of the deformation gradient (rest cells are cubes). */
  vec3 n = cross(jv, jw) * nrm.x + cross(jw, ju) * nrm.y + cross(ju, jv) * nrm.z;
  gl_Position = mvp * vec4(p, 1.0);
  v_pos = (view.model_view * vec4(p, 1.0)).xyz;
  v_nrm = mat3(view.normal_matrix) * n;
}
"""

_FRAGMENT = """
void main()
{
  vec3 N = (view.mode.x > 0.5) ? normalize(v_nrm) : normalize(cross(dFdx(v_pos), dFdy(v_pos)));
  if (view.mode.x > 0.5 && !gl_FrontFacing) {
    N = -N;
  }
  vec3 I = (view.mode.y > 0.5) ? normalize(vec3(v_pos.xy, -v_pos.z)) : vec3(0.0, 0.0, 1.0);
  vec3 base = view.base_color.rgb;
  if (view.material.w > 0.5) {
    FragColor = vec4(base, view.base_color.a);
    return;
  }
  float rough = view.material.x;
  bool spec_on = view.material.z > 0.5;
  vec3 diff_col = spec_on ? base * (1.0 - view.material.y) : base;
  vec3 spec_col = spec_on ? mix(vec3(0.05), base, view.material.y) : vec3(0.0);
  vec3 diff_light = view.ambient.rgb;
  vec3 spec_light = view.ambient.rgb;
  vec3 R = -reflect(I, N);
  for (int k = 0; k < 4; k++) {
    vec3 L = view.light_dir[k].xyz;
    float w = view.light_diffuse[k].a;  /* wrap: how soft the light is */
    float nl = dot(L, N);
    diff_light += clamp((nl + w) / ((1.0 + w) * (1.0 + w)), 0.0, 1.0) * view.light_diffuse[k].rgb;
    if (spec_on) {
      float shininess = exp2(10.0 * (1.0 - rough) * (1.0 - w) + 1.0);
      float blinn = pow(clamp(dot(normalize(L + I), N), 0.0, 1.0), shininess) * clamp(nl, 0.0, 1.0) *
                    (shininess * 0.125 + 1.0);
      float we = mix(w, 1.0, rough);
      float env = clamp((dot(L, R) + we) / ((1.0 + we) * (1.0 + we)), 0.0, 1.0);
      spec_light += mix(blinn, env, w * w) * view.light_specular[k].rgb;
    }
  }
  if (spec_on) {
    float fresnel = exp2(-8.35 * clamp(dot(N, I), 0.0, 1.0)) * (1.0 - rough);
    spec_col = mix(spec_col, vec3(1.0), fresnel);
  }
  vec3 color = diff_light * diff_col * (1.0 - dot(spec_col, vec3(1.0 / 3.0))) + spec_light * spec_col;
  FragColor = vec4(color, view.base_color.a);
}
"""


def _build_shader():
    import gpu
    info = gpu.types.GPUShaderCreateInfo()
    for slot, (kind, name) in enumerate((("VEC3", "rest"), ("VEC3", "nrm"), ("FLOAT", "cell"), ("VEC3", "frac"))):
        info.vertex_in(slot, kind, name)
    iface = gpu.types.GPUStageInterfaceInfo("larap_preview_iface")
    iface.smooth("VEC3", "v_pos")
    iface.smooth("VEC3", "v_nrm")
    info.vertex_out(iface)
    info.sampler(0, "FLOAT_2D", "nodes_tx")
    info.sampler(1, "FLOAT_2D", "cells_tx")
    info.push_constant("MAT4", "mvp")
    info.push_constant("FLOAT", "cell_size")
    info.push_constant("INT", "tex_width")
    info.typedef_source(_TYPEDEFS)
    info.uniform_buf(0, "LarapView", "view")
    info.fragment_out(0, "VEC4", "FragColor")
    info.vertex_source(_VERTEX)
    info.fragment_source(_FRAGMENT)
    return gpu.shader.create_from_info(info)


def _shader():
    if _SHADER[0] is None and not _SHADER[1]:
        try:
            _SHADER[0] = _build_shader()
        except Exception as exc:  # no GPU shader support: the caller writes the mesh instead
            _SHADER[1] = "%s: %s" % (type(exc).__name__, exc)
            print("LARAP preview:", _SHADER[1])
    return _SHADER[0]


# ----------------------------------------------------------------------------------------------
# Lighting like Blender's Solid mode

def _studio_light(shading):
    lights = bpy.context.preferences.studio_lights
    for sl in lights:
        if sl.type == "STUDIO" and sl.name == shading.studio_light:
            return sl
    for sl in lights:
        if sl.type == "STUDIO":
            return sl
    return None


def _lighting(obj, shading):
    """Uniform values for the view's Solid-mode lighting and colour."""
    mat = obj.active_material
    kind = getattr(shading, "color_type", "MATERIAL")
    if kind == "OBJECT":
        base = tuple(obj.color)
    elif kind == "SINGLE":
        base = tuple(shading.single_color) + (1.0,)
    elif kind == "MATERIAL" and mat is not None:
        base = tuple(mat.diffuse_color)
    else:
        base = (0.8, 0.8, 0.8, 1.0)
    rough = float(mat.roughness) if mat is not None else 0.4
    metal = float(mat.metallic) if mat is not None else 0.0
    alpha = float(shading.xray_alpha) if shading.show_xray else 1.0
    out = {"base_color": (base[0], base[1], base[2], alpha), "ambient": (0.0, 0.0, 0.0, 0.0)}
    sl = _studio_light(shading) if shading.light == "STUDIO" else None
    if shading.light == "MATCAP":  # approximated by the default studio light
        sl = _studio_light(type("S", (), {"studio_light": "Default"})())
    spec = bool(shading.show_specular_highlight and sl is not None)
    out["material"] = (rough, metal, 1.0 if spec else 0.0, 1.0 if shading.light == "FLAT" else 0.0)
    for k in range(4):
        light = sl.solid_lights[k] if sl is not None and k < len(sl.solid_lights) else None
        if light is not None and light.use:
            out["light_dir%d" % k] = tuple(light.direction) + (0.0,)
            out["light_diffuse%d" % k] = tuple(light.diffuse_color) + (float(light.smooth),)
            out["light_specular%d" % k] = tuple(light.specular_color) + (0.0,)
        else:
            out["light_dir%d" % k] = (1.0, 0.0, 0.0, 0.0)
            out["light_diffuse%d" % k] = (0.0, 0.0, 0.0, 0.0)
            out["light_specular%d" % k] = (0.0, 0.0, 0.0, 0.0)
    if sl is not None:
        out["ambient"] = tuple(sl.light_ambient) + (0.0,)
    else:
        out["ambient"] = (1.0, 1.0, 1.0, 0.0)
    return out


def _view_block(values):
    """The LarapView uniform block as float32 bytes (std140: mat4 column-major, then vec4s)."""
    parts = []
    for name in _VIEW_FIELDS:
        v = values[name]
        if name in ("model_view", "normal_matrix"):
            parts.append(np.array(v, dtype=np.float32).T.reshape(-1))  # column-major
        else:
            parts.append(np.array(v, dtype=np.float32))
    for name in ("light_dir", "light_diffuse", "light_specular"):
        for k in range(4):
            parts.append(np.array(values["%s%d" % (name, k)], dtype=np.float32))
    return np.concatenate(parts).tobytes()


# ----------------------------------------------------------------------------------------------
# Drawing

def _visible_here(obj, view_layer, space):
    """Would Blender draw ``obj`` in this view were it not hidden by us?"""
    if obj.hide_viewport:
        return False
    if space is not None and getattr(space, "local_view", None) is not None and not obj.local_view_get(space):
        return False
    return scene_index.in_visible_collection(obj, view_layer)


def draw():
    if not _SHOWN:
        return
    import gpu
    ctx = bpy.context
    rv3d, space, view_layer = ctx.region_data, ctx.space_data, ctx.view_layer
    if rv3d is None or view_layer is None:
        return
    shader = _shader()
    if shader is None:
        return
    for obj in scene_index.bound_meshes(ctx.scene):
        try:
            entry = _SHOWN.get(obj.larap.runtime_id)
            if entry is None or entry.get("hidden", False):  # not shown, or hidden by the artist
                continue
            if not scene_index.in_view_layer(obj, view_layer):
                continue
            rt = runtime(obj)
            if rt is None or rt.deformer is None or rt.lattice_nodes is None:
                continue
            if not _visible_here(obj, view_layer, space):
                continue
            g = _GPU.get(obj.larap.runtime_id)  # built by show() (prepare), never here
            if g is None or g.deformer is not rt.deformer or g.counts != rt.counts:
                continue
            if g.batch is None:
                g.upload(shader)
            if g.version != rt.pose_version:
                g.set_pose(rt.lattice_nodes, rt.pose_version)
        except (ReferenceError, AttributeError, RuntimeError):
            continue
        mw = obj.matrix_world
        mv = rv3d.view_matrix @ mw
        shading = space.shading
        values = _lighting(obj, shading)
        values["model_view"] = mv
        values["normal_matrix"] = mv.to_3x3().inverted_safe().transposed().to_4x4()
        values["mode"] = (1.0 if draws_smooth(obj) else 0.0, 1.0 if rv3d.is_perspective else 0.0, 0.0, 0.0)
        block = gpu.types.GPUUniformBuf(_view_block(values))
        shader.bind()
        shader.uniform_float("mvp", rv3d.perspective_matrix @ mw)
        shader.uniform_float("cell_size", g.cell_size)
        shader.uniform_int("tex_width", TEX_WIDTH)
        shader.uniform_block("view", block)
        shader.uniform_sampler("nodes_tx", g.nodes_tex)
        shader.uniform_sampler("cells_tx", g.cells_tex)
        xray = shading.show_xray
        gpu.state.depth_test_set("NONE" if xray else "LESS_EQUAL")
        gpu.state.depth_mask_set(not xray)
        gpu.state.blend_set("ALPHA" if xray else "NONE")
        gpu.state.face_culling_set("BACK" if shading.show_backface_culling else "NONE")
        g.batch.draw(shader)
        gpu.state.face_culling_set("NONE")
        gpu.state.depth_mask_set(False)
        gpu.state.depth_test_set("NONE")
        gpu.state.blend_set("NONE")


def register():
    """The draw callback is added in background mode too (it never runs there)."""
    global _DRAW_HANDLE
    if _DRAW_HANDLE is None:
        _DRAW_HANDLE = bpy.types.SpaceView3D.draw_handler_add(draw, (), "WINDOW", "POST_VIEW")


def unregister():
    global _DRAW_HANDLE
    reset_all()  # never leave an object hidden behind a preview
    _GPU.clear()
    _SHADING.clear()
    if _DRAW_HANDLE is not None:
        try:
            bpy.types.SpaceView3D.draw_handler_remove(_DRAW_HANDLE, "WINDOW")
        except ValueError:
            pass
        _DRAW_HANDLE = None
