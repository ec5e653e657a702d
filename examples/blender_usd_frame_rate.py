"""A Blender add-on: on USD import the scene plays at the stage's frame rate.

Blender 5.0's USD import takes a cache's frame range but not its rate (the scene keeps 24 fps), so a warpsph cache
written at 25 or 30 fps plays 4 % or 20 % slow. This import hook sets the scene's ``fps`` / ``fps_base`` from the
stage's ``framesPerSecond`` (else ``timeCodesPerSecond``): 25 -> 25 / 1, 29.97 -> 30 / 1.001.

Install: *Edit > Preferences > Add-ons > Install from Disk* with this file, or run it once in Blender's Python
console (``exec(open(PATH).read()); register()``). ``tests/test_blender.py`` checks it with Blender 5.0.1.
"""

import bpy

bl_info = {
    "name": "warpsph: USD frame rate",
    "description": "On USD import, set the scene's frame rate from the stage (framesPerSecond)",
    "blender": (4, 2, 0),
    "category": "Import-Export",
}


class WarpsphSceneRate(bpy.types.USDHook):
    """On USD import: the scene plays at the stage's framesPerSecond (else timeCodesPerSecond)."""

    bl_idname = "warpsph_scene_rate"
    bl_label = "Scene frame rate from the USD stage"

    @staticmethod
    def on_import(import_context):
        stage = import_context.get_stage()
        fps = stage.GetFramesPerSecond() if stage.HasAuthoredMetadata("framesPerSecond") else \
            stage.GetTimeCodesPerSecond()
        render = bpy.context.scene.render
        render.fps = max(1, round(fps))
        render.fps_base = render.fps / fps
        return True


def register():
    bpy.utils.register_class(WarpsphSceneRate)


def unregister():
    bpy.utils.unregister_class(WarpsphSceneRate)
