"""A bounded SDL front end for POV-Ray scenes with ``lathe`` and ``sor``
objects: enough of POV-Ray 3.7's language (expressions, ``#declare``,
conditionals, loops, macros, includes, objects and their transforms) to
find and place every lathe and sor of a scene, skipping the rest.

Modules, one job each: :mod:`.tokens` (text to tokens), :mod:`.values`
(value types and transform matrices), :mod:`.expressions` (expressions and
built-in functions), :mod:`.interpreter` (directives, macros, includes,
limits), :mod:`.objects` (object statements, transforms, materials) and
:mod:`.scene` (the walk over a scene and its placed objects).
"""

from .scene import Placement, SceneObject, SceneResult, walk_scene
from .tokens import PovError
from .values import Material

__all__ = ["Material", "Placement", "PovError", "SceneObject", "SceneResult", "walk_scene"]
