"""Uploads: validated as ``dataset show`` validates, segmented, keyed and registered.

An upload is one recording (C3D or Motive CSV) with its annotation entry, or a whole dataset
folder as an archive (zip or tar). Either way the service writes a dataset folder (the
service's own skills file and dataset-wide settings, the upload's entries and files) and runs
:func:`~nonprehensile.demonstrations.dataset.check_dataset` on it: the problems are those the
CLI lists, line for line. Each accepted demonstration is cut at its events
(:func:`~nonprehensile.demonstrations.segment.segment_demonstration`), each piece flattened
and registered to the clusterer of its arc (one store per pair of contact events, as the
pipeline clusters them: a :class:`~nonprehensile.motion.pgstore.PostgresStore` or, in a SQLite
file, a :class:`~nonprehensile.service.sqlite.SQLiteArcStore`), all in one database
transaction together with the upload's row: a killed server leaves an upload whole or absent.

Recalibration runs in the background (:meth:`Registry.recalibrate`): the heavy part (principal
components, re-keying, clustering) works on a snapshot without any lock; only the final write
of the new keys takes the arc's lock, and the samples registered meanwhile are registered to
the new model then.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import tempfile
import uuid
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Any, BinaryIO, NamedTuple

import numpy as np
from numpy.typing import NDArray

from nonprehensile.demonstrations.dataset import (
    _TOP_KEYS,
    ANNOTATION_FILES,
    DATASET_FORMAT,
    DEFAULT_FINGERS,
    DEFAULT_GAP_LIMIT,
    DEFAULT_TOLERANCE_MM,
    Dataset,
    Demonstration,
    KnownSkills,
    Problem,
    _annotations_file,
    check_dataset,
    dataset_path,
)
from nonprehensile.demonstrations.segment import SkillGraphs, segment_demonstration, skill_graphs
from nonprehensile.errors import InputError, NonprehensileError
from nonprehensile.io import load_document, read_skills
from nonprehensile.motion.clustering import HilbertClusterer
from nonprehensile.motion.store import MemoryStore
from nonprehensile.motion.tablestore import TableStore
from nonprehensile.references import flatten_segments
from nonprehensile.service.archive import MAX_ARCHIVE_FILES, unpack_archive
from nonprehensile.service.db import Pool, arc_store, snapshot
from nonprehensile.service.errors import (
    TEMP_PREFIX,
    ArcMismatch,
    Forbidden,
    Rejected,
    disk_error,
)
from nonprehensile.skills.contacts import format_event

__all__ = ["MAX_ARCHIVE_FILES", "ArcCheck", "ArcMismatch", "Forbidden", "Registry", "Rejected",
           "Template", "UploadKey", "arc_identity", "canonical_annotation", "content_hash",
           "extract_archive", "load_template"]

#: Name of an arc clusterer's state in its store's meta table.
STATE = "hilbert_clusterer"
#: Sample count at the arc's last background recalibration (meta, decimal text).
RECAL_N = "service_recalibrated_at"
#: Samples an arc gathers before its first clustering.
DEFAULT_INIT_SIZE = 10
#: Samples registered to an arc between two checkpoints of its model (the samples after a
#: checkpoint are registered again, deterministically, when the model is rebuilt).
DEFAULT_CHECKPOINT = 64
#: The arc's generation (meta): changes with every registration and recalibration.
GENERATION = "service_generation"
#: Samples the checkpointed model had seen (meta, decimal text).
CHECKPOINT_N = "service_checkpoint_n"
#: The arc's model's current cluster of each micro-cluster id (meta, little-endian int64),
#: written with every generation: "cluster now" maps each sample's micro-cluster id through
#: it. (``np_samples.label`` is the id a sample got when registered; the model's clusters
#: move at recalibrations, which rewrite no sample's id.)
CLUSTER_MAP = "service_clusters"
#: What the arc's store holds (meta, UTF-8 text of :func:`arc_identity`): written when the
#: store gets its first sample, checked before any is added (the store's name is only the
#: arc's place in the skill graphs, which another skills file gives to another arc).
ARC_IDENTITY = "service_arc"
_TRAJECTORY_SUFFIXES = (".c3d", ".csv")
#: The value of each dataset-wide setting when the annotations leave it out (None: as the
#: recordings declare); an archive's settings must be the service's, given or left out.
_SETTING_DEFAULTS: dict[str, Any] = {
    "format": DATASET_FORMAT, "scale": 1.0, "gap_limit": DEFAULT_GAP_LIMIT,
    "fingers": dict(DEFAULT_FINGERS), "markers": [], "object_markers": {}, "rigid_body": None,
    "axes": None, "units": None, "tolerance_mm": DEFAULT_TOLERANCE_MM}


@dataclass(frozen=True, eq=False)
class Template:
    """The service's dataset context: the skills and dataset-wide settings every upload uses.

    Attributes
    ----------
    top : dict
        The annotations' dataset-wide keys (``format``, ``skills`` as an absolute path,
        ``scale``, ``gap_limit``, ``fingers``, ``markers``).
    graphs : SkillGraphs
        The skill graphs of the skills.
    arcs : dict
        ``(group, source, target)`` to the arc's store name, e.g. ``rolling-g0-n1-n2``.
    arc_skills : dict
        Store name to the number of skills sharing the arc (the clusters asked for).
    """

    top: dict[str, Any]
    graphs: SkillGraphs
    arcs: dict[tuple[int, Any, Any], str] = field(default_factory=dict)
    arc_skills: dict[str, int] = field(default_factory=dict)
    #: The skills file as read once (path, object, skills): every upload's check uses it
    #: instead of reading the file again (a third of a small upload's time).
    known: KnownSkills | None = None
    #: Store name to the arc's identity (:func:`arc_identity`): what its samples are.
    identities: dict[str, str] = field(default_factory=dict)
    #: ``(skill, motion index)`` to the store name of its arc.
    motion_arcs: dict[tuple[str, int], str] = field(default_factory=dict)
    #: Store name to the part of its identity the skills' motions do not change: the maneuver
    #: and the source and target contact events (``rolling: (G,a) -> (R1,f) ∧ (G,a)``).
    edges: dict[str, str] = field(default_factory=dict)


def load_template(spec: str | Path) -> Template:
    """The context of a dataset folder (or bundled name): its skills and settings."""
    root = dataset_path(spec)
    ann = _annotations_file(root)
    if ann is None:
        raise InputError(f"{root}: no annotations file; expected one of {list(ANNOTATION_FILES)}")
    doc = load_document(ann)
    if not isinstance(doc, Mapping) or not isinstance(doc.get("skills"), str):
        raise InputError(f"{ann}: the annotations must name a skills file")
    top = {k: v for k, v in doc.items() if k != "demonstrations"}
    top["skills"] = str((root / doc["skills"]).resolve())
    poly, skills = read_skills(top["skills"])
    graphs = skill_graphs(poly, skills)
    arcs: dict[tuple[int, Any, Any], str] = {}
    arc_keys: dict[str, set[str]] = {}
    motions: dict[str, list[tuple[str, int]]] = {}
    motion_arcs: dict[tuple[str, int], str] = {}
    for g, graph in enumerate(graphs.graphs):
        names = {node: i for i, node in enumerate(graph.nodes)}
        skills_of = {s.name: s for s in graphs.groups[g]}
        for u, v, key, data in graph.edges(keys=True, data=True):
            name = f"{graph.graph['maneuver']}-g{g}-n{names[u]}-n{names[v]}"
            arcs[(g, u, v)] = name
            arc_keys.setdefault(name, set()).add(str(key))
            step = skills_of[str(key)].motions.index(data["motion"])
            motions.setdefault(name, []).append((str(key), step))
            motion_arcs[(str(key), step)] = name
    identities, edges = {}, {}
    for (g, u, v), name in arcs.items():
        graph = graphs.graphs[g]
        identities[name] = arc_identity(graph.graph["maneuver"], _node_text(graph, u),
                                        _node_text(graph, v), motions[name])
        edges[name] = _edge_text(graph.graph["maneuver"], _node_text(graph, u),
                                 _node_text(graph, v))
    return Template(top, graphs, arcs, {n: len(k) for n, k in arc_keys.items()},
                    (Path(top["skills"]), poly, tuple(skills)), identities, motion_arcs,
                    edges)


def _node_text(graph: Any, node: Any) -> str:
    """A skill graph's node as text: its contact event in the paper's canonical notation
    (``(R1,f) ∧ (G,a)``, :func:`~nonprehensile.skills.contacts.format_event`), and which of
    the chain's visits to those contacts it is when not the first (a rotation's last
    ``(G,a)`` is ``(G,a) #2``)."""
    text = format_event(graph.nodes[node]["event"], "paper")
    return text if node[1] == 0 else f"{text} #{node[1] + 1}"


def arc_identity(maneuver: str, source: str, target: str,
                 motions: list[tuple[str, int]]) -> str:
    """What an arc's store holds, as one line: the maneuver, the arc's source and target
    contact events, and the skills' motions on it (``skill`` motion ``index``, 0-based).

    e.g. ``rolling: (R1,f) ∧ (G,a) -> (R1,f) ∧ (G,E(a,d)) (push-roll motion 1)``.
    """
    on = ", ".join(f"{skill} motion {step}" for skill, step in sorted(motions))
    return f"{_edge_text(maneuver, source, target)} ({on})"


def _edge_text(maneuver: str, source: str, target: str) -> str:
    return f"{maneuver}: {source} -> {target}"


def _same_edge(recorded: str, edge: str) -> bool:
    """Whether an arc's recorded identity is of the arc ``edge`` (:func:`_edge_text`), its
    motion list aside. (An event's text is followed by `` ∧ ``, `` #`` or its end, never by
    `` (``: the edge is the identity's text up to its motions' parenthesis.)"""
    return recorded.startswith(edge + " (") and recorded.endswith(")")


class ArcCheck(NamedTuple):
    """What :meth:`Registry.check_arcs` recorded: the arc stores whose identity was recorded
    for the first time (written before stores recorded their arcs: ``adopted``) and those
    whose identity was rewritten (the skills' motions on the arc changed: ``updated``)."""

    adopted: list[str]
    updated: list[str]


class UploadKey(NamedTuple):
    """The identity of an upload.

    Attributes
    ----------
    digest : str
        Its content hash, of the canonical annotation (:func:`canonical_annotation`).
    given : str
        The hash of the annotation's text as given, which versions before canonical
        annotations stored uploads under: an upload stored so is found by it (it equals
        ``digest`` for an annotation already in canonical form, as the bundled ones are).
    """

    digest: str
    given: str


def canonical_annotation(demo: Demonstration) -> dict[str, Any]:
    """An upload's annotation as its identity reads it: as the checked demonstration has it.

    Its states are :class:`~nonprehensile.states.State`'s, theta normalised to ``[0, 360)``
    (``0``, ``360`` and ``-0.0`` are ``0.0``), the skill's where the annotation leaves them
    out; its event times are floats (``1`` is ``1.0``, ``-0.0`` is ``0.0``). Written out
    here, not by ``Demonstration.to_dict``, so that a change there moves no stored hash.
    """
    return {"skill": demo.skill.name, "initial": demo.initial.to_dict(),
            "final": demo.final.to_dict(),
            "events": [{"id": e.id, "time": float(e.time) + 0.0} for e in demo.events]}


def upload_key(mentor: str, demo: Demonstration, entry: Mapping[str, Any],
               data: bytes) -> UploadKey:
    """The identity of the upload of ``demo`` (checked) from ``entry`` and ``data``."""
    return UploadKey(content_hash(mentor, canonical_annotation(demo), data),
                     content_hash(mentor, entry, data))


def content_hash(mentor: str, entry: Mapping[str, Any], data: bytes) -> str:
    """SHA-256 of an upload: the mentor, the annotation (without the file's name), the bytes.

    The identity of an upload is this hash of its :func:`canonical_annotation`."""
    ann = {k: v for k, v in entry.items() if k not in ("file", "mentor")}
    # through JSON once: keys of other types (YAML's 1:) become the strings JSON makes of
    # them, which sort (a str-keyed annotation comes out the same)
    ann = json.loads(json.dumps(ann))
    h = hashlib.sha256()
    h.update(mentor.encode() + b"\0")
    h.update(json.dumps(ann, sort_keys=True, separators=(",", ":")).encode() + b"\0")
    h.update(data)
    return h.hexdigest()


def _safe_name(filename: str | None) -> str:
    name = PurePosixPath((filename or "").replace("\\", "/")).name
    shown = repr((filename or "")[:80])
    if (not name or name.startswith(".") or len(name) > 200
            or any(ord(c) < 32 or ord(c) == 127 for c in name)
            or len(name.encode("utf-8", "surrogatepass")) > 255):
        raise Rejected(f"the recording's file name {shown} is not usable; name it like "
                       "take_01.c3d or take_01.csv", status=400)
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:
        raise Rejected(f"the recording's file name {shown} is not valid UTF-8; name it like "
                       "take_01.c3d", status=400) from None
    if PurePosixPath(name).suffix.lower() not in _TRAJECTORY_SUFFIXES:
        raise Rejected(f"{name}: unknown trajectory format {PurePosixPath(name).suffix!r}; "
                       "use .c3d or a Motive .csv", status=400)
    return name


def _problems(problems: list[Problem], root: Path) -> Rejected:
    lines = [str(p) for p in problems]
    return Rejected(f"{len(lines)} problem(s) in the upload, nothing was stored: "
                    + "; ".join(lines), lines)


@contextlib.contextmanager
def single_upload(template: Template, mentor: str, filename: str | None, data: bytes,
                  annotation: Any) -> Iterator[tuple[Dataset, list[UploadKey]]]:
    """Check one recording and its annotation entry as ``dataset show`` would.

    Yields the one-demonstration dataset and its identity (as a list of one).
    """
    if not isinstance(annotation, Mapping):
        raise Rejected("the annotation must be a JSON object: one entry of the annotations' "
                       "'demonstrations' list (skill, initial, final, events)", status=400)
    name = _safe_name(filename)
    given = annotation.get("mentor")
    if given is not None and given != mentor:
        raise Forbidden(f"the annotation names mentor {given!r} but the token is {mentor!r}'s; "
                        "a mentor uploads only their own demonstrations")
    entry = {**annotation, "file": name, "mentor": mentor}
    with tempfile.TemporaryDirectory(prefix=TEMP_PREFIX) as tmp:
        root = Path(tmp)
        doc = {**template.top, "demonstrations": [entry]}
        try:
            (root / name).write_bytes(data)
            (root / ANNOTATION_FILES[0]).write_text(json.dumps(doc))
        except OSError as exc:
            raise disk_error(exc, f"the recording {name!r}") from None
        ds, problems = check_dataset(root, known_skills=template.known)
        if ds is None:
            raise _problems(problems, root)
        yield ds, [upload_key(mentor, ds.demonstrations[0], entry, data)]


def extract_archive(source: bytes | BinaryIO, dest: Path, max_bytes: int) -> Path:
    """Unpack a zip or tar archive of a dataset folder into ``dest``; the dataset's root.

    Every member is checked as it comes (:func:`~nonprehensile.service.archive.unpack_archive`:
    names, kinds, at most :data:`MAX_ARCHIVE_FILES` members and ``max_bytes`` unpacked).
    """
    unpack_archive(source, dest, max_bytes=max_bytes)
    # the dataset's root: the folder holding the annotations file (the top or its one child)
    for cand in [dest, *sorted(p for p in dest.iterdir() if p.is_dir())]:
        if _annotations_file(cand) is not None:
            return cand
    raise Rejected(f"the archive holds no annotations file ({', '.join(ANNOTATION_FILES)}) at "
                   "its top or in its one folder", status=422)


@contextlib.contextmanager
def archive_upload(template: Template, mentor: str, source: bytes | BinaryIO,
                   max_bytes: int) -> Iterator[tuple[Dataset, list[UploadKey]]]:
    """Check a dataset archive as ``dataset show`` would; yields it and each demo's identity.

    The archive's own skills file is not used: its demonstrations must be of the service's
    skills, and its dataset-wide settings must be the service's (given or left out); a key
    the annotations do not have is refused with the line ``dataset show`` prints for it.
    """
    with tempfile.TemporaryDirectory(prefix=TEMP_PREFIX) as tmp:
        root = extract_archive(source, Path(tmp), max_bytes)
        ann = _annotations_file(root)
        assert ann is not None
        try:
            doc = load_document(ann)
        except InputError as exc:
            raise Rejected(str(exc)) from None
        if not isinstance(doc, Mapping) or not isinstance(doc.get("demonstrations"), list):
            raise Rejected(f"{ann.name}: the annotations must be an object with a "
                           "'demonstrations' list (see docs/dataset.md)")
        for key, value in doc.items():
            if key in ("demonstrations", "skills") or key not in _TOP_KEYS:
                continue  # unknown keys: refused below by the dataset check, as the CLI does
            service = template.top.get(key, _SETTING_DEFAULTS.get(key))
            if value != service:
                raise Rejected(f"{ann.name}: '{key}' is {value!r:.80}, the service's datasets "
                               f"have {service!r:.80}; export the archive with the service's "
                               "settings")
        for i, item in enumerate(doc["demonstrations"]):
            if isinstance(item, Mapping) and "mentor" in item and item["mentor"] != mentor:
                raise Forbidden(f"{ann.name} (demonstration {i}): mentor "
                                f"{str(item.get('mentor'))[:100]!r} is not the token's mentor "
                                f"{mentor!r}; a mentor uploads only their own demonstrations")
        unknown = {str(k): v for k, v in doc.items() if k not in _TOP_KEYS}
        try:
            ann.unlink()
            (root / ANNOTATION_FILES[0]).write_text(json.dumps(
                {**template.top, **unknown, "demonstrations": doc["demonstrations"]}))
        except OSError as exc:
            raise disk_error(exc, "the archive's annotations") from None
        ds, problems = check_dataset(root, known_skills=template.known)
        if ds is None:
            raise _problems(problems, root)
        hashes = []
        for d, item in zip(ds.demonstrations, doc["demonstrations"], strict=True):
            hashes.append(upload_key(mentor, d, item, (root / d.file).read_bytes()))
        if len({h.digest for h in hashes}) != len(hashes):
            raise Rejected("the archive holds the same demonstration twice")
        yield ds, hashes


class Registry:
    """Registers demonstrations to their arcs' clusterers in the service's database.

    Parameters
    ----------
    pool : Pool
        Autocommit connections to the database (tables created).
    template : Template
    init_size : int
        Samples an arc gathers before its first clustering.
    growth : float
        A background recalibration of an arc is due when its count reaches ``growth`` times
        the count at its last one.
    seed : int
        Random seed of the arcs' clusterers.
    """

    def __init__(self, pool: Pool, template: Template, *,
                 init_size: int = DEFAULT_INIT_SIZE, growth: float = 2.0,
                 checkpoint: int = DEFAULT_CHECKPOINT, seed: int = 0) -> None:
        self.pool = pool
        self.template = template
        self.init_size = init_size
        self.growth = growth
        self.checkpoint = checkpoint
        self.seed = seed
        # arc -> (generation, clusterer): the model this process left the arc in
        self._cache: dict[str, tuple[bytes, HilbertClusterer]] = {}
        # arc -> (generation, cluster map) of arcs last written before maps were stored
        self._rebuilt: dict[str, tuple[bytes, NDArray[np.int64]]] = {}
        #: True once :meth:`check_arcs` passed (an application built on this registry does
        #: not check again)
        self.arcs_checked = False

    # ------------------------------------------------------------------ arcs' identities

    def _mismatch(self, arc: str, what: str) -> ArcMismatch:
        skills = Path(str(self.template.top.get("skills", "skills"))).name
        return ArcMismatch(
            f"the store's arc {arc!r} {what}, but the skills file {skills} makes it "
            f"{self.template.identities[arc]}; serve this store with the skills file it was "
            "written with (the same skills in the same order), or give --store a new database")

    def check_arcs(self) -> ArcCheck:
        """Refuse to serve a store whose arcs are not those of the skills file.

        Every arc store the skills file names is compared with the identity it recorded when
        it got its first sample (:data:`ARC_IDENTITY`): its maneuver and source and target
        contact events must be the same. When only the skills' motions on the arc differ (a
        skill left out of the skills file, or one added whose motion shares the arc), and
        for a store written before identities were recorded (it has samples and none), the
        store is checked against its uploads instead: the skill and motion of each of its
        segments must be filed under it by the skills file; then the identity is recorded
        (rewritten, or recorded for the first time: the migration). Nothing else is written.

        Returns
        -------
        ArcCheck
            The stores whose identity was recorded now (adopted) and rewritten (updated).

        Raises
        ------
        ArcMismatch
            One line naming the arc, what its store holds, what the skills file makes it,
            and how to serve it.
        """
        with self.pool.connection() as conn, conn.transaction(), \
                contextlib.ExitStack() as locks:
            self._check_unnamed(conn)
            legacy, changed = [], {}
            for arc in sorted(self.template.identities):
                store = arc_store(conn, arc)
                have = store.get_meta(ARC_IDENTITY)
                if have is not None:
                    text = have.decode()
                    if text == self.template.identities[arc]:
                        continue
                    if not _same_edge(text, self.template.edges[arc]):
                        raise self._mismatch(arc, f"holds {text}")
                    changed[arc] = text  # other motions on the same arc: check its segments
                    legacy.append(store)
                elif store.n_samples:
                    legacy.append(store)
            if not legacy:
                self.arcs_checked = True
                return ArcCheck([], [])
            names = {s.name for s in legacy}
            # each store's lock before its segments are read (in the uploads' order: sorted):
            # an upload in flight under another skills file commits its segments first, and
            # the check below sees them (read before, they were missed, and the record was
            # rewritten over a segment of a skill it leaves out)
            for store in legacy:
                locks.enter_context(store.transaction())
            rows = conn.execute(
                "SELECT DISTINCT p.skill, u.step, u.arc FROM np_upload_samples u "
                "JOIN np_uploads p ON p.hash = u.hash ORDER BY 3, 1, 2").fetchall()
            for skill, step, arc in rows:
                want = self.template.motion_arcs.get((skill, int(step)))
                if arc in names and want != arc:
                    held = (f"holds {changed[arc]}, with" if arc in changed else
                            "(written before stores recorded their arcs) holds")
                    raise self._mismatch(arc, (
                        f"{held} segments of {skill} motion {step} ("
                        + (f"filed under {want!r} by" if want else "a motion not in")
                        + " this skills file)"))
            for store in legacy:
                store.put_meta(ARC_IDENTITY, self.template.identities[store.name].encode())
        self.arcs_checked = True
        return ArcCheck(sorted(names - set(changed)), sorted(changed))

    def _check_unnamed(self, conn: Any) -> None:
        """Refuse a store whose arc stores the skills file no longer names hold an arc it
        names otherwise: a skill left out renumbered the graph (``push-roll``, the only skill
        on its arcs), and the arc's samples would be split between its old store and a new
        one (the store then served whole by neither skills file)."""
        named = self.template.identities
        # (every store that recorded its arc: a store of an earlier version that is no
        # longer named recorded none, and is left alone)
        for name, value in conn.execute(
                "SELECT store, value FROM np_meta WHERE name = %s ORDER BY 1",
                (ARC_IDENTITY,)).fetchall():
            if name in named:
                continue
            text = bytes(value).decode()
            for arc, edge in sorted(self.template.edges.items()):
                if _same_edge(text, edge):
                    skills = Path(str(self.template.top.get("skills", "skills"))).name
                    raise ArcMismatch(
                        f"the store's arc {name!r} holds {text}, which the skills file {skills} "
                        f"names {arc!r}; serve this store with the skills file it was written "
                        "with (the same skills in the same order), or give --store a new "
                        "database")

    def _check_arc(self, store: TableStore) -> bool:
        """Before adding to an arc's store (its lock held): it must hold the arc the skills
        file gives its name, with the same skills' motions (a store whose motions differ is
        refused too: only :meth:`check_arcs`, at a start, checks its segments and rewrites
        it). True: a new store, whose first sample records its arc."""
        have = store.get_meta(ARC_IDENTITY)
        if have is None:
            if store.n_samples:
                # (written by an earlier version, or another process, since this one started)
                raise ArcMismatch(
                    f"the store's arc {store.name!r} holds {store.n_samples} sample(s) written "
                    "without a record of their arc (by an earlier version, since this server "
                    "started); restart `nonprehensile serve` on the store: it checks them "
                    "against their uploads' skills and records the arc")
            return True
        text = have.decode()
        if text != self.template.identities[store.name]:
            if _same_edge(text, self.template.edges[store.name]):
                # the same arc, other skills' motions on it, recorded since this server
                # started (another server's skills file): its segments are checked at a start
                # only, never here, under the lock
                raise ArcMismatch(
                    f"the store's arc {store.name!r} holds {text} (recorded since this server "
                    f"started), but the skills file makes it "
                    f"{self.template.identities[store.name]}; restart `nonprehensile serve` "
                    "with this skills file: it checks the arc's segments against it and "
                    "records the arc's motions")
            raise self._mismatch(store.name, f"holds {text}")
        return False

    # ------------------------------------------------------------------ clusterers

    def _new_clusterer(self, arc: str, store: TableStore) -> HilbertClusterer:
        k = self.template.arc_skills.get(arc, 1)
        # recalibrations are the background job's: the clusterer never runs one inline
        # (beyond completing its first batch), so an upload never waits for one
        return HilbertClusterer(k if k > 1 else None, init_size=self.init_size, growth=1e12,
                                drift_fraction=1e12, store=store, random_state=self.seed)

    def _clusterer(self, arc: str, store: TableStore) -> HilbertClusterer:
        """The arc's clusterer, bound to ``store`` (whose lock the caller holds).

        The one this process left the arc in is reused when the arc's generation says nobody
        changed it since; otherwise the last checkpoint is loaded and the samples stored after
        it are registered again (to a copy, in memory): registration is deterministic and
        does not depend on how the stream is chunked, so this rebuilds exactly the model that
        registered them (and checks it: the keys and ids must come out as stored).
        """
        gen = store.get_meta(GENERATION)
        cached = self._cache.get(arc)
        if cached is not None and gen is not None and cached[0] == gen:
            c = cached[1]
            c.store = store
            return c
        state = store.get_meta(STATE)
        n = store.n_samples
        if state is None:
            if n:
                raise NonprehensileError(f"arc {arc}: {n} samples but no clusterer state; "
                                         "the store was changed outside the service")
            return self._new_clusterer(arc, store)
        n_seen = int((store.get_meta(CHECKPOINT_N) or b"0").decode())
        c = _replayed(arc, state, n_seen, store.vectors(0, n), store.keys(), store.labels(),
                      store.micro_ids())
        c.store = store
        return c

    def _save(self, store: TableStore, c: HilbertClusterer, checkpoint: bool,
              pending: dict[str, tuple[bytes, HilbertClusterer]]) -> None:
        """Record the arc's new generation, and a checkpoint of the model when asked."""
        if checkpoint:
            store.put_meta(STATE, c.save_state())
            store.put_meta(CHECKPOINT_N, str(c.n_samples_seen_).encode())
        # (a few bytes a micro-cluster: far less than one sample's vector)
        store.put_meta(CLUSTER_MAP, c.micro_labels_.astype("<i8").tobytes())
        gen = f"{c.n_samples_seen_}:{uuid.uuid4().hex}".encode()
        store.put_meta(GENERATION, gen)
        pending[store.name] = (gen, c)

    def _checkpoint_due(self, store: TableStore, c: HilbertClusterer) -> bool:
        # the first batch's model is saved as soon as it exists; later ones every
        # `checkpoint` samples (the samples after a checkpoint are its log)
        if c.n_samples_seen_ <= self.init_size:
            return True
        last = int((store.get_meta(CHECKPOINT_N) or b"0").decode())
        return c.n_samples_seen_ - last >= self.checkpoint

    # ------------------------------------------------------------------ uploads

    def register(self, mentor: str, dataset: Dataset, hashes: list[UploadKey],
                 kind: str) -> list[dict[str, Any]]:
        """Register each demonstration (skipping those already stored); their replies.

        Each is registered in its own transaction. Before the first, every demonstration is
        segmented and every arc they touch is checked (:meth:`_check_arc`, read-only, no
        lock): an archive one of whose arcs is refused stores nothing. (Each registration
        checks its arcs again under their locks.)"""
        cuts = [self._segments(d) for d in dataset.demonstrations]
        if len(cuts) > 1:
            with self.pool.connection() as conn, snapshot(conn):
                for arc in sorted({a for _, _, arcs in cuts for a in arcs}):
                    self._check_arc(arc_store(conn, arc))
        return [self._register_one(mentor, d, h, kind, cut)
                for d, h, cut in zip(dataset.demonstrations, hashes, cuts, strict=True)]

    def _segments(self, demo: Demonstration) -> tuple[list[Any], Any, list[str]]:
        """A demonstration's segments, their flattened vectors and each one's arc."""
        segments = segment_demonstration(demo, self.template.graphs,
                                         max_gap=int(self.template.top.get("gap_limit", 12)))
        vectors = flatten_segments(segments)
        arcs = [self.template.arcs[(s.arc.group, s.arc.source, s.arc.target)] for s in segments]
        return segments, vectors, arcs

    def _register_one(self, mentor: str, demo: Demonstration, key: UploadKey, kind: str,
                      cut: tuple[list[Any], Any, list[str]]) -> dict[str, Any]:
        segments, vectors, arcs = cut
        pending: dict[str, tuple[bytes, HilbertClusterer]] = {}
        try:
            reply = self._register_tx(mentor, demo, key, kind, segments, vectors, arcs,
                                      pending)
        except BaseException:
            # rolled back: what the clusterers registered in it is gone from the database
            for arc in set(arcs):
                self._cache.pop(arc, None)
            raise
        self._cache.update(pending)
        return reply

    def _register_tx(self, mentor: str, demo: Demonstration, key: UploadKey, kind: str,
                     segments: list[Any], vectors: Any, arcs: list[str],
                     pending: dict[str, tuple[bytes, HilbertClusterer]]) -> dict[str, Any]:
        with self.pool.connection() as conn, conn.transaction():
            digest = key.digest
            if key.given != digest:
                # stored by a version that hashed the annotation's text as given: the same
                # upload, under that hash (no stored hash is rewritten)
                stored = {h for (h,) in conn.execute(
                    "SELECT hash FROM np_uploads WHERE hash IN (%s, %s)",
                    (key.digest, key.given)).fetchall()}
                if key.given in stored and key.digest not in stored:
                    digest = key.given
            # claims the hash; an identical upload in flight waits here for this one's commit
            claimed = conn.execute(
                "INSERT INTO np_uploads (hash, mentor, file, skill, kind, reply) "
                "VALUES (%s, %s, %s, %s, %s, %s) ON CONFLICT (hash) DO NOTHING "
                "RETURNING hash", (digest, mentor, demo.file, demo.skill.name, kind, "{}")
            ).fetchone()
            if claimed is None:
                # stored before; withdrawn since: the same mentor's upload of it again puts it
                # back (its samples never left the arcs; the listings count it again)
                back = conn.execute(
                    "UPDATE np_uploads SET withdrawn = false WHERE hash = %s AND withdrawn "
                    "RETURNING hash", (digest,)).fetchone()
                return {**self.upload(conn, digest), "duplicate": back is None,
                        "reinstated": back is not None}
            with contextlib.ExitStack() as stack:
                stores = {}
                fresh = set()
                for arc in sorted(set(arcs)):  # one lock order: no deadlock between uploads
                    stores[arc] = arc_store(conn, arc)
                    stack.enter_context(stores[arc].transaction())
                    if self._check_arc(stores[arc]):
                        fresh.add(arc)
                for step, (seg, arc) in enumerate(zip(segments, arcs, strict=True)):
                    store = stores[arc]
                    c = self._clusterer(arc, store)
                    c.partial_fit(vectors[step : step + 1])
                    self._save(store, c, self._checkpoint_due(store, c), pending)
                    if arc in fresh:
                        # (after the new clusterer: making one clears its store's blobs)
                        store.put_meta(ARC_IDENTITY, self.template.identities[arc].encode())
                        fresh.discard(arc)
                    conn.execute(
                        "INSERT INTO np_upload_samples (hash, step, arc, sample) "
                        "VALUES (%s, %s, %s, %s)", (digest, seg.step, arc, store.n_samples - 1))
            reply = self.upload(conn, digest)
            conn.execute("UPDATE np_uploads SET reply = %s WHERE hash = %s",
                         (json.dumps(reply), digest))
        return {**reply, "duplicate": False, "reinstated": False}

    def upload(self, conn: Any, digest: str) -> dict[str, Any]:
        """An upload's document: who, what, and each segment's arc, sample and cluster now
        (the arc's model's current cluster of the sample).

        ``conn`` is in a transaction or a :func:`~nonprehensile.service.db.snapshot`: the
        samples and the arcs' cluster maps are read from one state."""
        row = conn.execute("SELECT mentor, file, skill, kind, withdrawn FROM np_uploads "
                           "WHERE hash = %s", (digest,)).fetchone()
        if row is None:
            raise Rejected(f"no upload {digest}", status=404)
        rows = conn.execute(
            "SELECT u.step, u.arc, u.sample, s.micro, s.label FROM np_upload_samples u "
            "JOIN np_samples s ON s.store = u.arc AND s.id = u.sample "
            "WHERE u.hash = %s ORDER BY u.step", (digest,)
        ).fetchall()
        maps = self._cluster_maps(conn, {r[1] for r in rows})
        segs = [(st, arc, sample, _cluster_now(maps, arc, micro, label))
                for st, arc, sample, micro, label in rows]
        held = dict(conn.execute(
            "SELECT store, count(*) FROM np_samples GROUP BY store").fetchall()) if any(
            label < 0 for *_, label in segs) else {}

        def pending(arc: str) -> dict[str, str]:
            # a fresh arc collects its first batch before anything is clustered: say so
            # (``cluster`` is null until then) and when the clusters will be named
            k = self.template.arc_skills.get(arc, 1)
            need = max(self.init_size, 3, k + 1)
            return {"pending": f"not clustered yet: arc {arc!r} holds {held.get(arc, 0)} "
                               f"sample(s) and is first clustered at {need}; then replies "
                               "name the cluster (GET /clusters lists them)"}

        return {
            "upload": digest, "mentor": row[0], "file": row[1], "skill": row[2],
            "kind": row[3], "withdrawn": bool(row[4]),
            "segments": [{"step": st, "arc": arc, "sample": int(sample),
                          "cluster": None if label < 0 else int(label),
                          **(pending(arc) if label < 0 else {})}
                         for st, arc, sample, label in segs],
        }

    def _cluster_maps(self, conn: Any, arcs: set[str]) -> dict[str, NDArray[np.int64]]:
        """Each arc's current cluster of every micro-cluster id (:data:`CLUSTER_MAP`), read
        on ``conn`` (a transaction or a snapshot: with the samples it maps)."""
        meta: dict[str, dict[str, bytes]] = {}
        for store, name, value in conn.execute(
                "SELECT store, name, value FROM np_meta WHERE name IN (%s, %s)",
                (CLUSTER_MAP, GENERATION)).fetchall():
            if store in arcs:
                meta.setdefault(store, {})[name] = bytes(value)
        out = {}
        for arc in sorted(arcs):
            have = meta.get(arc, {})
            if CLUSTER_MAP in have:
                out[arc] = np.frombuffer(have[CLUSTER_MAP], dtype="<i8").astype(np.int64)
                continue
            # last written before the maps were stored: the model rebuilt as an upload to
            # the arc would rebuild it (once per generation of the arc)
            gen = have.get(GENERATION)
            kept = self._rebuilt.get(arc)
            if kept is not None and gen is not None and kept[0] == gen:
                out[arc] = kept[1]
                continue
            store = arc_store(conn, arc)
            state = store.get_meta(STATE)
            if state is None:  # nothing clustered yet: every sample pending
                out[arc] = np.zeros(0, dtype=np.int64)
                continue
            n_seen = int((store.get_meta(CHECKPOINT_N) or b"0").decode())
            c = _replayed(arc, state, n_seen, store.vectors(0, store.n_samples), store.keys(),
                          store.labels(), store.micro_ids())
            out[arc] = c.micro_labels_
            if gen is not None:
                self._rebuilt[arc] = (gen, out[arc])
        return out

    def withdraw(self, mentor: str, digest: str) -> dict[str, Any]:
        """Withdraw an upload of ``mentor``'s (another's: :class:`Forbidden`)."""
        with self.pool.connection() as conn, conn.transaction():
            # (the mentor of an upload never changes: no row lock needed)
            row = conn.execute("SELECT mentor FROM np_uploads WHERE hash = %s",
                               (digest,)).fetchone()
            if row is None:
                raise Rejected(f"no upload {digest}", status=404)
            if row[0] != mentor:
                raise Forbidden(f"upload {digest} is {row[0]!r}'s; a mentor withdraws only "
                                "their own uploads")
            conn.execute("UPDATE np_uploads SET withdrawn = true WHERE hash = %s", (digest,))
            return self.upload(conn, digest)

    # ------------------------------------------------------------------ listings

    def clusters(self) -> list[dict[str, Any]]:
        """Every arc with samples: its clusters and their sizes (withdrawn uploads left out)."""
        with self.pool.connection() as conn, snapshot(conn):
            rows = conn.execute(
                "SELECT s.store, s.micro, s.label, count(*) FROM np_samples s "
                "LEFT JOIN np_upload_samples u ON u.arc = s.store AND u.sample = s.id "
                "LEFT JOIN np_uploads p ON p.hash = u.hash "
                "WHERE p.withdrawn IS NOT TRUE "
                "GROUP BY s.store, s.micro, s.label ORDER BY s.store"
            ).fetchall()
            recal = {store: bytes(value).decode() for store, value in conn.execute(
                "SELECT store, value FROM np_meta WHERE name = %s", (RECAL_N,)).fetchall()}
            maps = self._cluster_maps(conn, {r[0] for r in rows})
        out: dict[str, dict[str, Any]] = {}
        sizes: dict[str, dict[int, int]] = {}
        for store, micro, label, n in rows:
            arc = out.setdefault(store, {"arc": store, "samples": 0, "pending": 0,
                                         "clusters": [],
                                         "recalibrated_at": int(recal.get(store, 0))})
            arc["samples"] += int(n)
            now = _cluster_now(maps, store, micro, label)
            if now < 0:
                arc["pending"] += int(n)
            else:
                sizes.setdefault(store, {})
                sizes[store][now] = sizes[store].get(now, 0) + int(n)
        for store, by_id in sizes.items():
            out[store]["clusters"] = [{"id": k, "size": n} for k, n in sorted(by_id.items())]
        return list(out.values())

    def mentor_stats(self, mentor: str | None = None) -> list[dict[str, Any]]:
        """Per mentor: uploads, withdrawn, segments, and counts per skill and per cluster."""
        with self.pool.connection() as conn, snapshot(conn):
            where, args = ("WHERE p.mentor = %s", (mentor,)) if mentor else ("", ())
            ups = conn.execute(
                f"SELECT p.mentor, p.skill, p.withdrawn, count(*) FROM np_uploads p {where} "
                "GROUP BY p.mentor, p.skill, p.withdrawn ORDER BY 1, 2", args).fetchall()
            rows = conn.execute(
                "SELECT p.mentor, u.arc, s.micro, s.label, count(*) FROM np_uploads p "
                "JOIN np_upload_samples u ON u.hash = p.hash "
                "JOIN np_samples s ON s.store = u.arc AND s.id = u.sample "
                f"{where}{' AND' if where else 'WHERE'} NOT p.withdrawn "
                "GROUP BY 1, 2, 3, 4 ORDER BY 1, 2", args).fetchall()
            maps = self._cluster_maps(conn, {r[1] for r in rows})
        counted: dict[tuple[str, str, int], int] = {}
        for m, arc, micro, label, n in rows:
            key = (m, arc, _cluster_now(maps, arc, micro, label))
            counted[key] = counted.get(key, 0) + int(n)
        segs = sorted(counted.items())
        out: dict[str, dict[str, Any]] = {}
        for m, skill, withdrawn, n in ups:
            doc = out.setdefault(m, {"mentor": m, "uploads": 0, "withdrawn": 0, "segments": 0,
                                     "skills": {}, "clusters": []})
            if withdrawn:
                doc["withdrawn"] += int(n)
            else:
                doc["uploads"] += int(n)
                doc["skills"][skill] = doc["skills"].get(skill, 0) + int(n)
        for (m, arc, label), n in segs:
            doc = out[m]
            doc["segments"] += n
            doc["clusters"].append({"arc": arc, "cluster": None if label < 0 else label,
                                    "segments": n})
        return list(out.values())

    # ------------------------------------------------------------------ recalibration

    def arcs_due(self) -> list[str]:
        """Arcs whose count reached ``growth`` times the count at their last recalibration."""
        with self.pool.connection() as conn:
            rows = conn.execute(
                "SELECT s.store, max(s.id) + 1, m.value FROM np_samples s "
                "LEFT JOIN np_meta m ON m.store = s.store AND m.name = %s "
                "GROUP BY s.store, m.value ORDER BY s.store", (RECAL_N,)).fetchall()
        due = []
        for store, n, last in rows:
            last_n = int(bytes(last).decode()) if last else self.init_size
            if n >= self.init_size and n >= self.growth * last_n:
                due.append(store)
        return due

    def recalibrate(self, arc: str) -> dict[str, Any]:
        """Recalibrate one arc without blocking uploads (see the module notes)."""
        with self.pool.connection() as conn:
            # a consistent snapshot, read without the arc's lock (MVCC)
            with snapshot(conn):
                store = arc_store(conn, arc)
                state = store.get_meta(STATE)
                n0 = store.n_samples
                if state is None or n0 < self.init_size:
                    return {"arc": arc, "recalibrated": False, "samples": n0}
                n_seen = int((store.get_meta(CHECKPOINT_N) or b"0").decode())
                c = _replayed(arc, state, n_seen, store.vectors(0, n0), store.keys(),
                              store.labels(), store.micro_ids())
            snap = c.store
            c.recalibrate()  # the heavy part: no lock held
            with conn.transaction(), store.transaction():
                n1 = store.n_samples
                if n1 > n0:
                    # registered meanwhile: registered again, to the new model
                    c.partial_fit(store.vectors(n0, n1))
                store.update(0, snap.keys(), snap.labels())
                c.store = store
                pending: dict[str, tuple[bytes, HilbertClusterer]] = {}
                self._save(store, c, True, pending)
                store.put_meta(RECAL_N, str(n1).encode())
            self._cache.update(pending)
        return {"arc": arc, "recalibrated": True, "samples": n1, "during": n1 - n0,
                "clusters": int(c.n_clusters_)}


def _replayed(arc: str, state: bytes, n_seen: int, x: Any, keys: list[int],
              labels: Any, micro: Any) -> HilbertClusterer:
    """The clusterer of a checkpoint (``n_seen`` samples) with the later samples of ``x``
    registered again, on an in-memory store holding all of ``x``; checked against the keys,
    ids and micro-cluster ids stored for them (a stored micro id of -1, a sample registered
    before samples kept theirs, is not compared)."""
    n = len(keys)
    mem = MemoryStore()
    if n_seen:
        mem.add(x[:n_seen], keys[:n_seen], labels[:n_seen])
    c = HilbertClusterer.load_state(state, mem)
    if n > n_seen:
        c.partial_fit(x[n_seen:])
        kept = np.asarray(micro[n_seen:]) >= 0
        if mem.keys()[n_seen:] != keys[n_seen:] or not np.array_equal(
                mem.labels()[n_seen:], labels[n_seen:]) or not np.array_equal(
                mem.micro_ids()[n_seen:][kept], np.asarray(micro[n_seen:])[kept]):
            raise NonprehensileError(
                f"arc {arc}: registering samples {n_seen}..{n - 1} again after the checkpoint "
                "gave other keys, ids or micro-cluster ids than those stored; recalibrate the "
                "arc")
    return c


def _cluster_now(maps: dict[str, NDArray[np.int64]], arc: str, micro: int, label: int) -> int:
    """A sample's cluster in its arc's model now (-1: pending its arc's first clustering),
    from its micro-cluster id and the arc's map."""
    if label < 0:
        return -1
    if micro < 0:  # registered before samples kept their micro-cluster id: its id then
        return int(label)
    m = maps.get(arc)
    if m is None or micro >= m.size:
        raise NonprehensileError(
            f"arc {arc}: a sample of micro-cluster {micro} is not in the arc's model "
            f"({0 if m is None else m.size} micro-clusters); recalibrate the arc")
    return int(m[micro])


def registration_error(exc: Exception) -> NonprehensileError:
    """An error of segmenting a checked demonstration, as a rejection (a 422)."""
    if isinstance(exc, InputError) and not isinstance(exc, Rejected | Forbidden):
        return Rejected(str(exc))
    return exc if isinstance(exc, NonprehensileError) else NonprehensileError(str(exc))

