#!/usr/bin/env python3
"""Weak-scaling model of the MPM solver split over MPI processes.

    python3 benchmarks/mpi/model.py

Prints the table of benchmarks/RESULTS.md ("MPI: scaling measured and modelled"). Inputs are the
figures measured by bench_mpi / bench_mpm_step on this machine (marked MEASURED) and stated
assumptions about a cluster node and its network (marked ASSUMED). Per substep and rank:

  compute  = (N_own + g N_ghost) / R_node           ghosts only scatter (P2G with their stress)
  transfer = B N_ghost / bandwidth                  halo bytes; migration adds ~1% (bench_mpi)
  pack     = 2 B N_ghost / copy_rate                packing on the sender, unpacking on the receiver
  latency  = (4 + 2 log2 P) alpha                   two neighbour exchanges of two rounds each
                                                    (sizes, then bytes), two MPI_Allreduce
  efficiency = (N_own / R_node) / (compute + transfer + pack + latency)   (nothing overlaps today)

N_ghost is the particles of one grid-block column (4 cells, 8 particles per cell) on each side
that has a neighbour; bench_mpi's bytes per substep match it exactly (BM_Strong/64, np 2:
32 768 particles, 3.54 MB).
"""
import math

R_CORE = 8.4e6      # MEASURED: particle-steps/s of one core, 3D float MLS fixed corotated (bench_mpi BM_Strong/100, np 1)
G = 0.59            # MEASURED: P2G (stress + scatter) share of a substep (bench_mpm_step ms_p2g / total, 1 M particles)
B = 108             # bytes per 3D float MLS solid particle: x, v, m, V0, F, C, id
PPC = 8             # particles per cell
COLUMN = 4          # cells per grid-block column (4^3-node blocks)
CORES = 32          # ASSUMED: cores per node (2 x 16), one rank per node with 32 threads
THREAD_EFF = 0.8    # ASSUMED: 32-thread efficiency (measured 0.93 at 2 threads: 15.5-15.9 M vs 2 x 8.4 M)
COPY = 10e9         # ASSUMED: bytes/s a node packs or unpacks (gather of SoA channels, threaded)
NETWORKS = {"25 Gb/s (RoCE, 5 us)": (25e9 / 8, 5e-6), "100 Gb/s (InfiniBand, 2 us)": (100e9 / 8, 2e-6)}
N_TOTAL = 1e9       # the target scene
NODES = 64
R_NODE = CORES * R_CORE * THREAD_EFF


def step(n_own, n_ghost, ranks, bandwidth, alpha):
    # n_ghost < 0 marks a grid halo of -n_ghost particles' worth of bytes and no extra compute.
    compute = (n_own + G * max(n_ghost, 0)) / R_NODE
    n_ghost = abs(n_ghost)
    transfer = B * n_ghost / bandwidth
    pack = 2 * B * n_ghost / COPY
    latency = (4 + 2 * math.log2(max(ranks, 1))) * alpha
    total = compute + transfer + pack + latency
    return total, (n_own / R_NODE) / total


def geometries(p):
    """(name, particles per node, ghost particles per node) at p nodes, weak scaling: 1e9 / 64 per node."""
    n = N_TOTAL / NODES
    cells = n * p / PPC
    out = []
    # A cube growing in all three directions, cut into slabs along x.
    side = cells ** (1 / 3)
    ghost = 0 if p == 1 else 2 * COLUMN * side * side * PPC
    out.append(("cube, slabs (implemented)", n, ghost))
    # A channel (a flood down a street) of fixed 250 x 250 cell section, growing in length: slabs.
    section = 250 * 250
    ghost = 0 if p == 1 else 2 * COLUMN * section * PPC
    out.append(("channel 250 x 250 cells, slabs (implemented)", n, ghost))
    # The cube cut into p = k^3 boxes (a Cartesian split; not implemented): a one-column shell.
    k = round(p ** (1 / 3))
    box = (cells / p) ** (1 / 3)
    ghost = 0 if p == 1 else ((box + 2 * COLUMN) ** 3 - box ** 3) * PPC
    out.append(("cube, %d^3 boxes (projection)" % k, n, ghost))
    # The cube in slabs with a grid halo instead of ghost particles (a projection, not
    # implemented): each rank scatters its border blocks and sends the partial node sums that
    # fall in the neighbour's slab (kernel order 2 node layers, mass and momentum: 16 B a node),
    # then receives the neighbour's updated node values for its own gather (the same layers).
    # Charged as "ghosts" of equal bytes; no extra compute.
    nodes = 0 if p == 1 else 2 * 2 * 2 * side * side  # 2 sides x 2 messages x 2 layers
    out.append(("cube, slabs, grid halo (projection)", n, -nodes * 16 / B))
    return out


print("node: %d cores x %.1f M particle-steps/s x %.2f = %.0f M particle-steps/s; %.3g particles per node"
      % (CORES, R_CORE / 1e6, THREAD_EFF, R_NODE / 1e6, N_TOTAL / NODES))
print("one node: %.0f ms per substep (efficiency 1 by definition)" % (1e3 * N_TOTAL / NODES / R_NODE))
print()
print("| nodes | geometry | ghosts / own | halo MB per substep | network | substep ms | of which transfer ms | weak efficiency |")
print("| --- | --- | --- | --- | --- | --- | --- | --- |")
for p in (8, 64):
    for name, n, ghost in geometries(p):
        for net, (bw, alpha) in NETWORKS.items():
            t, eff = step(n, ghost, p, bw, alpha)
            print("| %d | %s | %.2f | %.0f | %s | %.0f | %.0f | %.2f |"
                  % (p, name, max(ghost, 0) / n, B * abs(ghost) / 1e6, net, 1e3 * t, 1e3 * B * abs(ghost) / bw, eff))
