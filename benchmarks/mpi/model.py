#!/usr/bin/env python3
"""Weak-scaling model of the MPM solver split over MPI processes.

    python3 benchmarks/mpi/model.py [--plot FILE.png]

Prints the tables of benchmarks/RESULTS.md ("MPI: the grid halo, measured and modelled"): first
the grid-halo bytes the model predicts for bench_mpi's cases (to hold against its measured
"halo kB/substep/rank"), then the projection for a cluster. Inputs are figures measured by
bench_mpi / bench_mpm_step on this machine (marked MEASURED) and stated assumptions about a
cluster node and its network (marked ASSUMED).

The grid halo (engine/src/mpm/distribution.h): at each border between two slabs, each of the two
ranks sends the other, per occupied grid block of its border column, that block's patch nodes in
the Order node layers the two columns share: Order x (4 + Order)^2 nodes of 16 B (float momentum
and mass) and the block's 3 int32 coordinates, 1164 B per block for the quadratic kernel, after an
8 B count. Per substep and rank:

  compute  = N_own / R_node                         no particle is scattered twice
  transfer = (H + M) / bandwidth                    H halo bytes, M migrating particles' bytes
  pack     = 2 (H + M) / copy_rate                  packing on the sender, unpacking on the receiver
  latency  = (4 + 2 log2 P) alpha                   two neighbour exchanges of two rounds each
                                                    (sizes, then bytes), two MPI_Allreduce
  efficiency = (N_own / R_node) / (compute + transfer + pack + latency)   (nothing overlaps)

For comparison the ghost-particle halo it replaced: every substep each rank received copies of its
neighbours' border columns (4 cells x the section x 8 particles x 108 B) and scattered them again
(0.59 of a particle-step each, the P2G share).
"""
import math
import sys

R_CORE = 8.4e6      # MEASURED: particle-steps/s of one core, 3D float MLS fixed corotated (bench_mpi BM_Strong/100, np 1)
G = 0.59            # MEASURED: P2G (stress + scatter) share of a substep (bench_mpm_step ms_p2g / total, 1 M particles)
B = 108             # bytes per 3D float MLS solid particle: x, v, m, V0, F, C, id
PPC = 8             # particles per cell
BLOCK = 4           # cells per grid block along an axis (4^3-node blocks in 3D)
ORDER = 2           # the quadratic kernel: a patch reaches 2 node layers into the next block
NODE = 16           # bytes per grid node sent (float momentum and mass)
BLOCK_BYTES = 3 * 4 + ORDER * (BLOCK + ORDER) ** 2 * NODE  # 1164 B: one block's slice of the halo
MIGRATION = 0.2     # MEASURED: migrating particles' bytes / halo bytes, jelly_cubes_3d on 2 processes (cubes thrown across the border at 2.5 m/s; 0 in bench_mpi)
CORES = 32          # ASSUMED: cores per node (2 x 16), one rank per node with 32 threads
THREAD_EFF = 0.8    # ASSUMED: 32-thread efficiency (measured 0.93 at 2 threads: 15.5-15.9 M vs 2 x 8.4 M)
COPY = 10e9         # ASSUMED: bytes/s a node packs or unpacks (gather of SoA channels, threaded)
NETWORKS = {"25 Gb/s (RoCE, 5 us)": (25e9 / 8, 5e-6), "100 Gb/s (InfiniBand, 2 us)": (100e9 / 8, 2e-6)}
N_TOTAL = 1e9       # the target scene
NODES = 64
R_NODE = CORES * R_CORE * THREAD_EFF


def halo_message(blocks_across):
    """Bytes one rank sends across one border: the count and the slices of the occupied blocks."""
    return 8 + blocks_across * BLOCK_BYTES


def bench_blocks_across(res):
    """Occupied blocks across the border column of bench_mpi's block (cells [res/4, 3 res/4) in y
    and z, two particles per cell per axis at 1/4 and 3/4): quadratic base nodes res/4 - 1 ..
    3 res/4 - 1, shifted by the grid's 3 padding nodes (engine/src/mpm: kPad), blocks of 4 nodes."""
    pad = 3
    lo, hi = res // 4 - 1 + pad, 3 * res // 4 - 1 + pad
    per_axis = hi // BLOCK - lo // BLOCK + 1
    return per_axis * per_axis


def step(n_own, halo_bytes, ghosts, ranks, bandwidth, alpha):
    """Substep time and weak efficiency; `ghosts` > 0 charges the replaced ghost-particle halo."""
    compute = (n_own + G * ghosts) / R_NODE
    sent = halo_bytes * (1 + MIGRATION) + B * ghosts
    transfer = sent / bandwidth
    pack = 2 * sent / COPY
    latency = (4 + 2 * math.log2(max(ranks, 1))) * alpha
    total = compute + transfer + pack + latency
    return total, sent, (n_own / R_NODE) / total


def geometries(p):
    """(name, particles per node, halo bytes per node, ghost particles per node) at p nodes,
    weak scaling: 1e9 / 64 per node; a middle rank (two borders)."""
    n = N_TOTAL / NODES
    cells = n * p / PPC
    out = []
    # A cube growing in all three directions, cut into slabs along x.
    side = cells ** (1 / 3)
    halo = 0 if p == 1 else 2 * halo_message((side / BLOCK) ** 2)
    out.append(("cube, slabs, grid halo", n, halo, 0))
    ghost = 0 if p == 1 else 2 * BLOCK * side * side * PPC
    out.append(("cube, slabs, ghost particles (replaced)", n, 0, ghost))
    # A channel (a flood down a street) of fixed 250 x 250 cell section, growing in length: slabs.
    section = 250 * 250
    halo = 0 if p == 1 else 2 * halo_message(section / BLOCK ** 2)
    out.append(("channel 250 x 250 cells, slabs, grid halo", n, halo, 0))
    return out


print("Grid-halo bytes predicted for bench_mpi (kB per substep per rank, mean over the ranks):")
print()
print("| case | occupied blocks across | np 2 | np 4 |")
print("| --- | --- | --- | --- |")
for name, res in (("BM_Strong/64", 64), ("BM_Strong/100", 100), ("BM_Weak/64", 64)):
    msg = halo_message(bench_blocks_across(res))
    # np ranks have np - 1 borders, each crossed by one message each way: 2 (np - 1) / np per rank.
    print("| %s | %d | %.1f | %.1f |" % (name, bench_blocks_across(res), msg * 2 * 1 / 2 / 1e3, msg * 2 * 3 / 4 / 1e3))
print()
print("node: %d cores x %.1f M particle-steps/s x %.2f = %.0f M particle-steps/s; %.3g particles per node"
      % (CORES, R_CORE / 1e6, THREAD_EFF, R_NODE / 1e6, N_TOTAL / NODES))
print("one node: %.0f ms per substep (efficiency 1 by definition)" % (1e3 * N_TOTAL / NODES / R_NODE))
print()
print("| nodes | geometry | MB sent per substep | network | substep ms | of which transfer ms | weak efficiency |")
print("| --- | --- | --- | --- | --- | --- | --- |")
for p in (8, 64):
    for name, n, halo, ghosts in geometries(p):
        for net, (bw, alpha) in NETWORKS.items():
            t, sent, eff = step(n, halo, ghosts, p, bw, alpha)
            print("| %d | %s | %.1f | %s | %.0f | %.1f | %.2f |"
                  % (p, name, sent / 1e6, net, 1e3 * t, 1e3 * sent / bw, eff))

if "--plot" in sys.argv:
    # Weak efficiency against the node count (1e9 / 64 particles per node), the README's figure.
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    nodes = [1, 2, 4, 8, 16, 32, 64, 128]
    fig, ax = plt.subplots(figsize=(6.4, 3.6), dpi=100)
    styles = {"cube, slabs, grid halo": "C0", "channel 250 x 250 cells, slabs, grid halo": "C2",
              "cube, slabs, ghost particles (replaced)": "C3"}
    for name, colour in styles.items():
        for net, (bw, alpha) in NETWORKS.items():
            eff = []
            for p in nodes:
                row = next(g for g in geometries(p) if g[0] == name)
                eff.append(step(row[1], row[2], row[3], p, bw, alpha)[2])
            ax.plot(nodes, eff, color=colour, linestyle="-" if bw > 5e9 else "--", marker="o", markersize=3,
                    label="%s, %s" % (name, net.split(" (")[0]))
    ax.axhline(0.85, color="0.6", linewidth=0.8)
    ax.set_xscale("log", base=2)
    ax.set_xticks(nodes)
    ax.set_xticklabels([str(n) for n in nodes])
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("nodes (32 cores each), 1.56e7 particles per node")
    ax.set_ylabel("weak efficiency (model)")
    ax.set_title("MPM split over processes: benchmarks/mpi/model.py", fontsize=10)
    ax.legend(fontsize=6.5, loc="lower left")
    fig.tight_layout()
    fig.savefig(sys.argv[sys.argv.index("--plot") + 1])
