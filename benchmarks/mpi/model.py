#!/usr/bin/env python3
"""Weak-scaling model of the MPM and FLIP solvers split over MPI processes.

    python3 benchmarks/mpi/model.py [--plot FILE.png]

Prints the tables of benchmarks/RESULTS.md ("MPI: boxes"): first the grid-halo bytes the model
predicts for bench_mpi's cases (to hold against its measured "halo kB/substep/rank"), then the
projection for a cluster. Inputs are figures measured by bench_mpi / bench_mpm_step on this
machine (marked MEASURED) and stated assumptions about a cluster node and its network (marked
ASSUMED).

The split (engine/src/mpm/domain_split.h): the lattice of grid blocks (4^3 nodes) is cut into
p_x x p_y x p_z boxes, the factorisation of the process count whose cuts cross the fewest block
faces, each cut balanced by particle counts. The grid halo (engine/src/mpm/distribution.h): a
block's patch reaches Order node layers into the next block along each axis, so each process
sends every process whose box touches its own, per occupied block of its box next to that box,
the block's patch nodes the two share (16 B each: float momentum and mass) after the block's 3
int32 coordinates: across a face Order (4 + Order)^2 nodes (1164 B a block, quadratic kernel),
across an edge Order^2 (4 + Order) (396 B), across a corner Order^3 (140 B). For bench_mpi the
prediction repeats the split and the halo's rules on the bench scene's particle counts exactly.

Per substep and rank:

  compute  = N_own / R_node                         no particle is scattered twice
  transfer = (H + M) / bandwidth                    H halo bytes, M migrating particles' bytes
  pack     = 2 (H + M) / copy_rate                  packing on the sender, unpacking on the receiver
  latency  = (4 + 2 log2 P) alpha + 4 peers o       two exchanges with the peers of two rounds each
                                                    (sizes, then bytes), two MPI_Allreduce, and
                                                    each message's overhead o
  efficiency = (N_own / R_node) / (compute + transfer + pack + latency)   (nothing overlaps)

For comparison, slabs (the split before boxes) and the ghost-particle halo before the grid halo:
every substep each rank received copies of its neighbours' border columns (4 cells x the section
x 8 particles x 108 B) and scattered them again (0.59 of a particle-step each, the P2G share).
"""
import itertools
import math
import sys

R_CORE = 8.4e6      # MEASURED: particle-steps/s of one core, 3D float MLS fixed corotated (bench_mpi BM_Strong/100, np 1)
G = 0.59            # MEASURED: P2G (stress + scatter) share of a substep (bench_mpm_step ms_p2g / total, 1 M particles)
B = 108             # bytes per 3D float MLS solid particle: x, v, m, V0, F, C, id
PPC = 8             # particles per cell
BLOCK = 4           # cells per grid block along an axis (4^3-node blocks in 3D)
ORDER = 2           # the quadratic kernel: a patch reaches 2 node layers into the next block
PATCH = BLOCK + ORDER
NODE = 16           # bytes per grid node sent (float momentum and mass)
HEAD = 3 * 4        # a block's coordinates
FACE_BYTES = HEAD + ORDER * PATCH ** 2 * NODE     # 1164 B: one block's nodes shared across a face
EDGE_BYTES = HEAD + ORDER ** 2 * PATCH * NODE     # 396 B: across an edge
CORNER_BYTES = HEAD + ORDER ** 3 * NODE           # 140 B: across a corner
MIGRATION = 0.2     # MEASURED: migrating particles' bytes / halo bytes, jelly_cubes_3d on 2 processes (cubes thrown across the border at 2.5 m/s; 0 in bench_mpi)
CORES = 32          # ASSUMED: cores per node (2 x 16)
THREAD_EFF = 0.8    # ASSUMED: 32-core efficiency (measured 0.93 at 2 threads: 15.5-15.9 M vs 2 x 8.4 M)
COPY = 10e9         # ASSUMED: bytes/s a node packs or unpacks (gather of SoA channels, threaded)
OVERHEAD = 0.5e-6   # ASSUMED: a message's software overhead on the sender and the receiver (LogP's o)
NETWORKS = {"25 Gb/s (RoCE, 5 us)": (25e9 / 8, 5e-6), "100 Gb/s (InfiniBand, 2 us)": (100e9 / 8, 2e-6)}
N_TOTAL = 1e9       # the target scene
NODES = 64
R_NODE = CORES * R_CORE * THREAD_EFF


# ---- The split and the halo's rules, as the engine applies them ----------------------------------

def process_grid(ranks, blocks):
    """Processes per axis (domain_split.h process_grid): the factorisation with every p_a <= blocks[a]
    whose cuts cross the fewest block faces; among equals the first in descending order per axis."""
    best, best_faces = None, math.inf

    def place(axis, left, p):
        nonlocal best, best_faces
        if axis == len(blocks) - 1:
            if left > blocks[axis]:
                return
            q = p + [left]
            faces = sum((q[a] - 1) * math.prod(blocks[b] for b in range(len(q)) if b != a) for a in range(len(q)))
            if faces < best_faces:
                best, best_faces = q, faces
            return
        for n in range(min(left, blocks[axis]), 0, -1):
            if left % n == 0:
                place(axis + 1, left // n, p + [n])

    place(0, ranks, [])
    return best


def balanced_cuts(counts, ranks):
    """domain_split.h balanced_cuts."""
    columns = len(counts)
    cuts = [0] * (ranks + 1)
    cuts[ranks] = columns
    total = sum(counts)
    below, k = 0.0, 0
    for r in range(1, ranks):
        target = total * r / ranks
        lo, hi = cuts[r - 1] + 1, columns - (ranks - r)
        while k < lo:
            below += counts[k]
            k += 1
        while k < hi and below + counts[k] <= target:
            below += counts[k]
            k += 1
        if k < hi and target - below > below + counts[k] - target:
            below += counts[k]
            k += 1
        cuts[r] = k
    return cuts


def box_split(counts, res, procs):
    """Each rank's box [lo, hi) of blocks (domain_split.h BoxSplit), for particle counts per block
    (a dict of block -> count): the axes with the most processes cut first, each part of a level
    by its own counts; rank digits in the order of the cuts."""
    dim = len(res)
    order = sorted(range(dim), key=lambda a: -procs[a])  # stable, as std::stable_sort
    boxes = [([0] * dim, list(res), counts)]
    for a in order:
        n = procs[a]
        parts = []
        for lo, hi, inside in boxes:
            column = [0.0] * res[a]
            for b, c in inside.items():
                column[b[a]] += c
            cuts = balanced_cuts(column, n)
            for i in range(n):
                l, h = list(lo), list(hi)
                l[a], h[a] = cuts[i], cuts[i + 1]
                parts.append((l, h, {b: c for b, c in inside.items() if cuts[i] <= b[a] < cuts[i + 1]}))
        boxes = parts
    return [(lo, hi) for lo, hi, _ in boxes]


def halo_bytes_per_rank(counts, res, procs):
    """Grid-halo bytes each rank sends per substep (distribution.h exchange_halo): per occupied
    border block and per other rank owning one of its 3^3 - 1 neighbours, the block's coordinates
    and the patch nodes whose class admits one of those neighbours."""
    boxes = box_split(counts, res, procs)
    dim = len(res)

    def owner(b):
        for r, (lo, hi) in enumerate(boxes):
            if all(lo[d] <= b[d] < hi[d] for d in range(dim)):
                return r
        return None

    offsets = [o for o in itertools.product((-1, 0, 1), repeat=dim) if any(o)]
    # Nodes of each class (per axis 0: l < ORDER, 1: between, 2: l >= BLOCK) and the offsets it admits.
    per_axis = {0: ORDER, 1: BLOCK - ORDER, 2: ORDER}
    classes = []
    for c in itertools.product((0, 1, 2), repeat=dim):
        admits = {o for o in offsets if all(o[d] == 0 or (o[d] == -1 and c[d] == 0) or (o[d] == 1 and c[d] == 2) for d in range(dim))}
        classes.append((math.prod(per_axis[x] for x in c), admits))
    sent = [0] * len(boxes)
    for b, c in counts.items():
        if c <= 0:
            continue
        me = owner(b)
        by_rank = {}
        for o in offsets:
            nb = tuple(b[d] + o[d] for d in range(dim))
            if all(0 <= nb[d] < res[d] for d in range(dim)):
                r = owner(nb)
                if r != me:
                    by_rank.setdefault(r, set()).add(o)
        for r, owned in by_rank.items():
            sent[me] += HEAD + NODE * sum(n for n, admits in classes if admits & owned)
    return sent


def bench_counts(res, stretch):
    """Particles per block of bench_mpi's scene (benchmarks/block_scene.h): cells [res/4, 3 res/4)
    in y and z and [res/4, res/4 + stretch res/2) in x, two particles per cell per axis at 1/4 and
    3/4, whose quadratic base nodes are c - 1 and c, shifted by the grid's 3 padding nodes."""
    pad = 3
    cells = [res * (stretch + 1) // 2, res, res]
    body = [(res // 4, res // 4 + stretch * res // 2), (res // 4, 3 * res // 4), (res // 4, 3 * res // 4)]
    nodes = [c + 1 + 2 * pad for c in cells]
    blocks = [(n + BLOCK - 1) // BLOCK for n in nodes]
    per_axis = []
    for a in range(3):
        column = [0] * blocks[a]
        for c in range(*body[a]):
            for base in (c - 1 + pad, c + pad):
                column[base // BLOCK] += 1
        per_axis.append(column)
    counts = {}
    for i, x in enumerate(per_axis[0]):
        for j, y in enumerate(per_axis[1]):
            for k, z in enumerate(per_axis[2]):
                if x * y * z:
                    counts[(i, j, k)] = x * y * z
    return counts, blocks


# ---- The cluster projection ----------------------------------------------------------------------

def box_halo(box, procs):
    """Halo bytes and peers of a rank inside the split (neighbours on every cut side), its box
    `box` blocks along each axis, every block of the box's faces occupied."""
    dim = len(box)
    cut = [procs[a] > 1 for a in range(dim)]
    halo, peers = 0.0, 0
    for a in range(dim):
        if cut[a]:
            halo += 2 * math.prod(box[b] for b in range(dim) if b != a) * FACE_BYTES
            peers += 2
    for a in range(dim):
        for b in range(a + 1, dim):
            if cut[a] and cut[b]:
                third = [c for c in range(dim) if c not in (a, b)]
                halo += 4 * (box[third[0]] if third else 1) * EDGE_BYTES
                peers += 4
    if all(cut):
        halo += 8 * CORNER_BYTES
        peers += 8
    return halo, peers


def step(n_own, halo_bytes, ghosts, ranks, peers, bandwidth, alpha):
    """A node's substep time and weak efficiency; `ghosts` > 0 charges the replaced ghost-particle
    halo. n_own, halo_bytes and ghosts are the node's (summed over its ranks); `peers` one rank's."""
    compute = (n_own + G * ghosts) / R_NODE
    sent = halo_bytes * (1 + MIGRATION) + B * ghosts
    transfer = sent / bandwidth
    pack = 2 * sent / COPY
    latency = (4 + 2 * math.log2(max(ranks, 1))) * alpha + 4 * peers * OVERHEAD
    total = compute + transfer + pack + latency
    return total, sent, (n_own / R_NODE) / total


def geometries(p):
    """(name, particles per node, halo bytes per node, ghost particles per node, ranks, peers,
    processes per axis) at p
    nodes, weak scaling: 1e9 / 64 particles per node; a rank inside the split (every side cut)."""
    n = N_TOTAL / NODES
    cells = n * p / PPC
    side = cells ** (1 / 3) / BLOCK  # blocks across the cube
    out = []
    # A cube growing in all three directions: boxes, one process per node (32 threads each).
    procs = process_grid(p, [int(side)] * 3)
    halo, peers = box_halo([side / q for q in procs], procs)
    out.append(("cube, boxes, a process per node", n, halo, 0, p, peers, procs))
    # The same cube, one process per core: the node sends its 32 ranks' halos (all counted as
    # leaving the node).
    procs = process_grid(p * CORES, [int(side)] * 3)
    halo, peers = box_halo([side / q for q in procs], procs)
    out.append(("cube, boxes, a process per core", n, CORES * halo, 0, p * CORES, peers, procs))
    # The cube in slabs (the split before boxes) and with ghost particles (the halo before the grid's).
    halo = 0 if p == 1 else 2 * side * side * FACE_BYTES
    out.append(("cube, slabs, a process per node", n, halo, 0, p, 0 if p == 1 else 2, [p, 1, 1]))
    ghost = 0 if p == 1 else 2 * BLOCK * (side * BLOCK) ** 2 * PPC
    out.append(("cube, slabs, ghost particles (replaced)", n, 0, ghost, p, 0 if p == 1 else 2, [p, 1, 1]))
    # A channel (a flood down a street) of fixed 250 x 250 cell section, growing in length.
    section = 250 / BLOCK
    length = cells / 250 ** 2 / BLOCK
    procs = process_grid(p, [int(length), int(section), int(section)])
    halo, peers = box_halo([length / procs[0], section / procs[1], section / procs[2]], procs)
    out.append(("channel 250 x 250 cells, a process per node", n, halo, 0, p, peers, procs))
    return out


# ---- FLIP split over processes (engine/src/flip/split.h) ------------------------------------------

FLIP_PARTICLE = 64      # bytes of a 3D float APIC particle sent: x, v (12 B each), id (4), c (3 x 12)
FLIP_FACE_E3 = 13       # bytes per face after the projection: u, pre-projection u, transfer weight (4 B each), valid (1)
FLIP_FACE_E4 = 4        # bytes per face after the extrapolation: u (APIC; FLIP adds its old u)
FLIP_RING = 16          # bytes per ring cell of the pressure: its row number (8) and its solution (8)


def flip_bytes_per_rank(cell_counts, cells, procs, band, ghost, reach):
    """Bytes each rank sends per substep in the split FLIP step, by the engine's rules: the split of
    4^3-cell blocks by particle counts (box_split), then to each peer (a rank whose box lies within
    `band` cells) the particles of its cells within `ghost` cells of the peer's box, the faces of its
    cells within `band` (after the projection) and `reach` (after the extrapolation) cells of it,
    and the ring of cells within 1 (row numbers, solution). A region's faces are its cells' lower
    faces, plus the domain's upper wall where the region reaches it. `cell_counts`: a function of a
    cell giving its particles."""
    dim = len(cells)
    blocks = [-(-c // BLOCK) for c in cells]
    counts = {}
    for c in itertools.product(*[range(n) for n in cells]):
        k = cell_counts(c)
        if k:
            b = tuple(x // BLOCK for x in c)
            counts[b] = counts.get(b, 0) + k
    boxes = [([l * BLOCK for l in lo], [min(h * BLOCK, cells[d]) for d, h in enumerate(hi)])
             for lo, hi in box_split(counts, blocks, procs)]

    def region(lo, hi, plo, phi, depth):
        rlo = [max(lo[d], plo[d] - depth) for d in range(dim)]
        rhi = [min(hi[d], phi[d] + depth) for d in range(dim)]
        return (rlo, rhi) if all(rlo[d] < rhi[d] for d in range(dim)) else None

    def faces(r):
        rlo, rhi = r
        n = [rhi[d] - rlo[d] for d in range(dim)]
        return sum(math.prod(n[b] + (1 if b == a and rhi[a] == cells[a] else 0) for b in range(dim)) for a in range(dim))

    sent = []
    for me, (lo, hi) in enumerate(boxes):
        total = 0
        for q, (plo, phi) in enumerate(boxes):
            if q == me or region(lo, hi, plo, phi, band) is None:
                continue
            g = region(lo, hi, plo, phi, ghost)
            if g:
                total += FLIP_PARTICLE * sum(cell_counts(c) for c in itertools.product(*[range(g[0][d], g[1][d]) for d in range(dim)]))
            total += FLIP_FACE_E3 * faces(region(lo, hi, plo, phi, band))
            e4 = region(lo, hi, plo, phi, reach)
            if e4:
                total += FLIP_FACE_E4 * faces(e4)
            ring = region(lo, hi, plo, phi, 1)
            if ring:
                total += FLIP_RING * math.prod(ring[1][d] - ring[0][d] for d in range(dim))
        sent.append(total)
    return sent


# The FLIP step on a cluster, per node (one process of CORES threads), a cube of liquid filling the
# domain, boxes of BOX cells across: compute = the one-process substep's phases, each scaled by
# what the split adds (the ghost particles' share of the particle phases, the window's share of the
# grid phases, the distributed pressure solve's cost per row), plus the modelled bytes on the network
# and the solve's latency.
R_FLIP = 1.92e6         # MEASURED: particle-steps/s of one core, 3D dam break (bench_flip --phases ... 20 1)
FLIP_SHARES = {"particles": 0.25, "grid": 0.15, "gather": 0.27, "project": 0.33}  # MEASURED: the same run's phases
# (sort + transfer_to_grid + boundaries; extrapolate + gravity + enforce_solids; transfer_to_particles; project)
PROJECT_FACTOR = 4.0    # MEASURED: the split's projection per pressure row over one process's (rank 0 of the dam
                        # break on 2 processes, 1 thread each: 1.82 s for half the rows against 0.904 s for all)
AMG_ITERATIONS = 15     # MEASURED: 13-16 to 1e-10 in poisson_check on 1-4 processes; taken as constant in the
                        # process count, the weak scalability reported for BoomerAMG (Baker, Falgout, Kolev & Yang,
                        # "Scaling hypre's multigrid solvers to 100,000 cores", 2012)
AMG_LEVELS = 8          # ASSUMED: levels of the hierarchy for 1e8 rows with aggressive coarsening
FLIP_BAND, FLIP_GHOST, FLIP_REACH = 12, 2, 5   # the engine's at cfl 5, midpoint, linear kernel


def flip_step(p, bandwidth, alpha):
    """(substep s, MB sent per node, weak efficiency) of the FLIP cube on p nodes, 1e9 particles in all."""
    n = N_TOTAL / NODES
    box = (n / PPC) ** (1 / 3)                       # cells across a node's box
    t1 = n / (CORES * R_FLIP * THREAD_EFF)
    if p == 1:
        return t1, 0.0, 1.0
    shell = lambda depth: ((box + 2 * depth) ** 3 - box ** 3)
    ghosts = shell(FLIP_GHOST) * PPC
    factor = (FLIP_SHARES["particles"] * (1 + ghosts / n) + FLIP_SHARES["grid"] * (box + 2 * FLIP_BAND) ** 3 / box ** 3
              + FLIP_SHARES["gather"] + FLIP_SHARES["project"] * PROJECT_FACTOR)
    sent = ghosts * FLIP_PARTICLE + 3 * shell(FLIP_BAND) * FLIP_FACE_E3 + 3 * shell(FLIP_REACH) * FLIP_FACE_E4
    peers = 26
    # The solve: every iteration a V-cycle (a halo exchange per level, down and up) and two reductions;
    # the setup about as many exchanges again.
    solve_latency = 2 * AMG_ITERATIONS * (2 * AMG_LEVELS * (alpha + peers * OVERHEAD) + 2 * math.log2(p) * alpha)
    total = t1 * factor + sent / bandwidth + 2 * sent / COPY + 4 * peers * OVERHEAD + solve_latency
    return total, sent, t1 / total


def main():
    print("Grid-halo bytes predicted for bench_mpi (kB per substep per rank, mean / largest over the ranks):")
    print()
    print("| case | np 2: split, kB | np 4: split, kB |")
    print("| --- | --- | --- |")
    for name, res, weak in (("BM_Strong/64", 64, False), ("BM_Strong/100", 100, False), ("BM_Weak/64", 64, True)):
        cells = []
        for np_ in (2, 4):
            counts, blocks = bench_counts(res, np_ if weak else 1)
            procs = process_grid(np_, blocks)
            sent = halo_bytes_per_rank(counts, blocks, procs)
            cells.append("%s: %.1f / %.1f" % (" x ".join(map(str, procs)), sum(sent) / np_ / 1e3, max(sent) / 1e3))
        print("| %s | %s | %s |" % (name, cells[0], cells[1]))
    print()
    print("Split FLIP bytes predicted for a 3D pool at rest (40^3 cells, liquid below y = 20 cells, 8 per cell,")
    print("APIC, linear kernel, cfl 5 midpoint: band 12, ghosts 2, reach 5), kB per substep, rank 0 / largest:")
    print()
    print("| processes | split | rank 0 | largest |")
    print("| --- | --- | --- | --- |")
    for np_ in (2, 4):
        cells = [40, 40, 40]
        procs = process_grid(np_, [10, 10, 10])
        sent = flip_bytes_per_rank(lambda c: 8 if c[1] < 20 else 0, cells, procs, 12, 2, 5)
        print("| %d | %s | %.0f | %.0f |" % (np_, " x ".join(map(str, procs)), sent[0] / 1e3, max(sent) / 1e3))
    print()
    print("node: %d cores x %.1f M particle-steps/s x %.2f = %.0f M particle-steps/s; %.3g particles per node"
          % (CORES, R_CORE / 1e6, THREAD_EFF, R_NODE / 1e6, N_TOTAL / NODES))
    print("one node: %.0f ms per substep (efficiency 1 by definition)" % (1e3 * N_TOTAL / NODES / R_NODE))
    print()
    print("| nodes | geometry | processes per axis (peers of a rank) | MB sent per substep per node | network | substep ms | of which transfer ms | weak efficiency |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for p in (8, 64):
        for name, n, halo, ghosts, ranks, peers, procs in geometries(p):
            for net, (bw, alpha) in NETWORKS.items():
                t, sent, eff = step(n, halo, ghosts, ranks, peers, bw, alpha)
                print("| %d | %s | %s (%d) | %.1f | %s | %.0f | %.1f | %.2f |"
                      % (p, name, " x ".join(map(str, procs)), peers, sent / 1e6, net, 1e3 * t, 1e3 * sent / bw, eff))
    print()
    print("FLIP: one node %.0f ms per substep (%.2f M particle-steps/s a core)" % (1e3 * flip_step(1, 1, 1)[0], R_FLIP / 1e6))
    print()
    print("| nodes | FLIP geometry | MB sent per substep per node | network | substep ms | of which transfer ms | weak efficiency |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for p in (8, 64):
        for net, (bw, alpha) in NETWORKS.items():
            t, sent, eff = flip_step(p, bw, alpha)
            print("| %d | cube of liquid, boxes, a process per node | %.1f | %s | %.0f | %.1f | %.2f |"
                  % (p, sent / 1e6, net, 1e3 * t, 1e3 * sent / bw, eff))


main()

if "--plot" in sys.argv:
    # Weak efficiency against the node count (1e9 / 64 particles per node), the README's figure.
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    nodes = [1, 2, 4, 8, 16, 32, 64, 128]
    fig, ax = plt.subplots(figsize=(6.4, 3.6), dpi=100)
    styles = {"cube, boxes, a process per node": "C0", "cube, boxes, a process per core": "C1",
              "cube, slabs, a process per node": "C7", "channel 250 x 250 cells, a process per node": "C2",
              "cube, slabs, ghost particles (replaced)": "C3"}
    for name, colour in styles.items():
        for net, (bw, alpha) in NETWORKS.items():
            eff = []
            for p in nodes:
                row = next(g for g in geometries(p) if g[0] == name)
                eff.append(step(row[1], row[2], row[3], row[4], row[5], bw, alpha)[2])
            ax.plot(nodes, eff, color=colour, linestyle="-" if bw > 5e9 else "--", marker="o", markersize=3,
                    label="%s, %s" % (name, net.split(" (")[0]))
    for net, (bw, alpha) in NETWORKS.items():
        ax.plot(nodes, [flip_step(p, bw, alpha)[2] for p in nodes], color="C4", linestyle="-" if bw > 5e9 else "--",
                marker="s", markersize=3, label="FLIP cube, boxes, a process per node, %s" % net.split(" (")[0])
    ax.axhline(0.85, color="0.6", linewidth=0.8)
    ax.set_xscale("log", base=2)
    ax.set_xticks(nodes)
    ax.set_xticklabels([str(n) for n in nodes])
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("nodes (32 cores each), 1.56e7 particles per node")
    ax.set_ylabel("weak efficiency (model)")
    ax.set_title("MPM and FLIP split over processes: benchmarks/mpi/model.py", fontsize=10)
    ax.legend(fontsize=5.5, loc="lower left", ncol=2)
    fig.tight_layout()
    fig.savefig(sys.argv[sys.argv.index("--plot") + 1])
