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

// The Principled op's inputs (PrincipledExtra `extra` or nullptr) and its closures at ctx: the two
// halves of its eval_closure_op, apart so that constant registers' inputs are made once.
PrincipledInputs principled_inputs(const ShaderOp& op, const ShaderOp* extra, const Float4* r);
void principled_closures(const PrincipledInputs& in, const ShaderOp& op, const ShaderOp* extra, const ShaderProgram& prog,
                         const Float4* r, const ShadingContext& ctx, ClosureList& out);

}  // namespace pl::detail
