# Rebuilds a scan in Blender from dispdec's base mesh and vector displacement map, with no
# dispdec in the loop: the settings the README gives, applied headless.
#   blender -b --factory-startup --python scripts/blender_displace.py -- DISP.obj DISP.exr OUT.obj LEVELS [PIXELS.f32]
# DISP.obj is the base with the map's UVs (`dispdec bake ... -o DISP.exr --kind vector`).
# OUT.obj is the evaluated mesh (modifiers applied). With PIXELS.f32, the EXR as Blender reads
# it (RGBA float32, rows bottom to top) is written there, for comparison with dispdec's PFM.
import array
import sys

import bpy

obj_path, exr_path, out_path, levels = sys.argv[sys.argv.index("--") + 1:][:4]
pixels_path = (sys.argv[sys.argv.index("--") + 1:] + [None])[4]
levels = int(levels)

bpy.ops.wm.read_factory_settings(use_empty=True)
# Keep the file's axes (no Y-up to Z-up turn): the vector map is in the file's object space.
bpy.ops.import_scene.obj(filepath=obj_path, axis_forward="Y", axis_up="Z", split_mode="OFF")
ob = bpy.context.selected_objects[0]
bpy.context.view_layer.objects.active = ob

sub = ob.modifiers.new("dispdec subdivision", "SUBSURF")
sub.subdivision_type = "SIMPLE"
sub.levels = levels
sub.render_levels = levels
sub.uv_smooth = "NONE"  # UVs interpolated linearly, as the atlas is

img = bpy.data.images.load(exr_path)
img.colorspace_settings.name = "Non-Color"
tex = bpy.data.textures.new("dispdec displacement", "IMAGE")
tex.image = img
tex.extension = "EXTEND"
tex.use_interpolation = True
tex.use_mipmap = False
tex.use_clamp = False  # keep negative displacements

disp = ob.modifiers.new("dispdec displacement", "DISPLACE")
disp.texture = tex
disp.texture_coords = "UV"
disp.direction = "RGB_TO_XYZ"
disp.space = "LOCAL"
disp.mid_level = 0.0
disp.strength = 1.0

bpy.ops.export_scene.obj(
    filepath=out_path, use_selection=True, use_mesh_modifiers=True, axis_forward="Y", axis_up="Z",
    use_normals=False, use_uvs=False, use_materials=False, use_triangles=True,
)
if pixels_path:
    buf = array.array("f", bytes(4 * len(img.pixels)))
    img.pixels.foreach_get(buf)
    with open(pixels_path, "wb") as f:
        buf.tofile(f)
print("dispdec-blender: wrote", out_path, "levels", levels, "image", img.size[0], "x", img.size[1])
