#pragma once
/// @file Marks per-element functions that compile for both the CPU and CUDA backends.
#if defined(__CUDACC__)
#define SONOSLICE_HOST_DEVICE __host__ __device__
#define SONOSLICE_INLINE __forceinline__
#else
#define SONOSLICE_HOST_DEVICE
#define SONOSLICE_INLINE inline __attribute__((always_inline))
#endif

/// Kernel sources are compiled once per instruction set (generic x86-64, AVX2, CUDA). Every
/// template they instantiate lives in an inline namespace named after that instruction set, so
/// the copies of one template built with different compiler flags never merge at link time
/// (an AVX2 instantiation must not end up called on a CPU without AVX2).
#ifndef SONOSLICE_KERNEL_ISA
#define SONOSLICE_KERNEL_ISA generic
#endif
