"""PLY files as NumPy arrays (no Blender needed): the particle frames, surface meshes and collider
meshes Slurry writes (docs/pipeline-outputs.md), in any of the three PLY encodings. The header is
read first, so the columns are found by name, whatever a scene's `output.attributes` wrote."""
import numpy as np

_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


class PlyElement:
    """One element: `count` rows, `columns` {name: array} for scalar properties and `lists`
    {name: (counts, flat values)} for list properties."""

    def __init__(self, name, count):
        self.name, self.count = name, count
        self.properties = []  # (name, dtype) or (name, (count dtype, item dtype)) for lists
        self.columns, self.lists = {}, {}

    def has_lists(self):
        return any(isinstance(t, tuple) for _, t in self.properties)


def read_header(path):
    """(format, comments, [PlyElement], header bytes) of a PLY file; raises ValueError naming the file."""
    with open(path, "rb") as f:
        if f.readline().strip() != b"ply":
            raise ValueError(f"{path}: not a PLY file")
        fmt, comments, elements = None, [], []
        while True:
            raw = f.readline()
            if not raw:
                raise ValueError(f"{path}: no end_header")
            words = raw.decode("ascii", "replace").split()
            if not words:
                continue
            if words[0] == "format":
                fmt = words[1]
            elif words[0] == "comment":
                comments.append(raw.decode("ascii", "replace").strip()[len("comment "):])
            elif words[0] == "element":
                elements.append(PlyElement(words[1], int(words[2])))
            elif words[0] == "property":
                if words[1] == "list":
                    elements[-1].properties.append((words[4], (_TYPES[words[2]], _TYPES[words[3]])))
                else:
                    elements[-1].properties.append((words[2], _TYPES[words[1]]))
            elif words[0] == "end_header":
                return fmt, comments, elements, f.tell()


def element_counts(path):
    """{element name: count} from the header alone."""
    return {e.name: e.count for e in read_header(path)[2]}


def read_ply(path):
    """(comments, {element name: PlyElement}) with every element's data read."""
    fmt, comments, elements, offset = read_header(path)
    with open(path, "rb") as f:
        f.seek(offset)
        data = f.read()
    if fmt == "ascii":
        _read_ascii(data, elements)
    elif fmt in ("binary_little_endian", "binary_big_endian"):
        _read_binary(data, elements, "<" if fmt == "binary_little_endian" else ">", path)
    else:
        raise ValueError(f"{path}: unknown PLY format {fmt!r}")
    return comments, {e.name: e for e in elements}


def _read_binary(data, elements, order, path):
    pos = 0
    for e in elements:
        if not e.has_lists():
            dtype = np.dtype([(n, order + t) for n, t in e.properties])
            rows = np.frombuffer(data, dtype, e.count, pos)
            pos += dtype.itemsize * e.count
            e.columns = {n: rows[n] for n, _ in e.properties}
            continue
        # Lists: fast path when every row's lists have the length of the first row's (the
        # triangles of a surface mesh), else row by row (a collider's polygons).
        layout, probe = [], pos
        for n, t in e.properties:
            if isinstance(t, tuple):
                k = int(np.frombuffer(data, order + t[0], 1, probe)[0]) if e.count else 0
                layout.append((n + "#count", order + t[0]))
                layout.append((n, order + t[1], (k,)))
                probe += np.dtype(t[0]).itemsize + k * np.dtype(t[1]).itemsize
            else:
                layout.append((n, order + t))
                probe += np.dtype(t).itemsize
        dtype = np.dtype(layout)
        rows = None
        if pos + dtype.itemsize * e.count <= len(data):
            rows = np.frombuffer(data, dtype, e.count, pos)
            for n, t in e.properties:
                if isinstance(t, tuple) and e.count and not np.all(rows[n + "#count"] == rows.dtype[n].shape[0]):
                    rows = None
                    break
        if rows is not None:
            pos += dtype.itemsize * e.count
            for n, t in e.properties:
                if isinstance(t, tuple):
                    k = rows.dtype[n].shape[0]
                    e.lists[n] = (np.full(e.count, k, np.int64), rows[n].reshape(-1).astype(np.int64))
                else:
                    e.columns[n] = rows[n]
            continue
        scalars = {n: [] for n, t in e.properties if not isinstance(t, tuple)}
        lists = {n: ([], []) for n, t in e.properties if isinstance(t, tuple)}
        for _ in range(e.count):
            for n, t in e.properties:
                if isinstance(t, tuple):
                    k = int(np.frombuffer(data, order + t[0], 1, pos)[0])
                    pos += np.dtype(t[0]).itemsize
                    lists[n][0].append(k)
                    lists[n][1].extend(np.frombuffer(data, order + t[1], k, pos).tolist())
                    pos += k * np.dtype(t[1]).itemsize
                else:
                    scalars[n].append(np.frombuffer(data, order + t, 1, pos)[0])
                    pos += np.dtype(t).itemsize
        e.columns = {n: np.array(v, dtype=t) for (n, t) in e.properties if not isinstance(t, tuple) for v in [scalars[n]]}
        e.lists = {n: (np.array(c, np.int64), np.array(v, np.int64)) for n, (c, v) in lists.items()}
    if pos > len(data):
        raise ValueError(f"{path}: truncated ({len(data)} bytes of data, the header declares more)")


def _read_ascii(data, elements):
    tokens = data.split()
    pos = 0
    for e in elements:
        if not e.has_lists():
            k = len(e.properties)
            block = np.array(tokens[pos:pos + k * e.count], dtype=np.float64).reshape(e.count, k)
            pos += k * e.count
            e.columns = {n: block[:, i].astype(t) for i, (n, t) in enumerate(e.properties)}
            continue
        scalars = {n: [] for n, t in e.properties if not isinstance(t, tuple)}
        lists = {n: ([], []) for n, t in e.properties if isinstance(t, tuple)}
        for _ in range(e.count):
            for n, t in e.properties:
                if isinstance(t, tuple):
                    k = int(tokens[pos])
                    lists[n][0].append(k)
                    lists[n][1].extend(int(x) for x in tokens[pos + 1:pos + 1 + k])
                    pos += 1 + k
                else:
                    scalars[n].append(float(tokens[pos]))
                    pos += 1
        e.columns = {n: np.array(scalars[n]).astype(t) for n, t in e.properties if not isinstance(t, tuple)}
        e.lists = {n: (np.array(c, np.int64), np.array(v, np.int64)) for n, (c, v) in lists.items()}
