#pragma once
/// @file How deep the JSON settings sonoslice reads may nest, whichever way they come: a file,
/// inline text, or Python values (dicts, lists) turned into JSON by the bindings.

namespace sonoslice {

/// Documents nested deeper are refused with an InputError naming the input. No setting of ours
/// nests more than a few levels (a sweep's "from", a rejection rule, a pose's rows); code that
/// walks a document recursively (the JSON library's writer, a sweep's base sampler, Python values
/// turned into JSON) would otherwise exhaust the stack on a file nested hundreds of thousands of
/// levels deep, or on a Python list that holds itself.
constexpr int kMaxJsonDepth = 64;

}  // namespace sonoslice
