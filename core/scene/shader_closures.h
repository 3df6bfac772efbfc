// The closure ops of shader programs, for eval_shader: included by shader.cpp and
// shader_closures.cpp alone.
#pragma once

#include "scene/shader.h"

namespace pl::detail {

// Adds what closure op `op` makes (closures, emission or holdout) to `out`, its inputs in
// registers r. `extra`: the PrincipledExtra op before a Principled op (one sets it, the other
// takes and clears it). Out of line on purpose: compiled apart, eval_shader and this run
// ~3 % fewer instructions per shade (callgrind, the call included) than as one function.
void eval_closure_op(const ShaderOp& op, const ShaderProgram& prog, const Float4* r, const ShadingContext& ctx,
                     const ShaderOp*& extra, ClosureList& out);

}  // namespace pl::detail
