"""Blender shader node trees → Pathlight shader programs (docs/core_api.md, issue 3).

A material's active output is walked from its Surface (and Volume) socket; value nodes become
register instructions, BSDF nodes become weighted closures. Constant sub-graphs are folded here,
so a material of constant inputs compiles to a few "const" ops and its closures.

Nothing here raises for a user's node tree: each unsupported node, link, setting or cycle is a
*problem*, noted with a fallback (documented at `_fallback_value` / `_fallback_shader`), and all
problems of one material are reported in ONE warning naming them.

The compiler uses virtual registers (unbounded) and a linear-scan allocation at the end maps
them onto the core's 64 registers.

The modules: compiler (ShaderCompiler: the walk, emitting ops, `compile_material`), graph
(following links through reroutes, mutes and groups), values (Val, constants), folding (constant
folding by the core's own evaluation, and the core's table of operation names), nodes_input / nodes_math / nodes_color /
nodes_vector / nodes_textures / tex_patterns / nodes_closures / volume (the node translators by
family), images (the scene's image table), uv_sets (UV map and attribute numbering) and
registers (dead-code elimination and register allocation).
"""

from .compiler import CompiledShader, ShaderCompiler, compile_material
from .folding import fold, mapping_matrix, math_ops, mix_blends, op_table, vector_math_ops
from .images import ImageData, ImageTable
from .registers import MAX_REGISTERS
from .uv_sets import UvSets

# What the add-on and the tests import from `export.shader`.
__all__ = ("CompiledShader", "ImageData", "ImageTable", "MAX_REGISTERS", "ShaderCompiler", "UvSets",
           "compile_material", "fold", "mapping_matrix", "math_ops", "mix_blends", "op_table",
           "vector_math_ops")
