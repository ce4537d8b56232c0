-- surfidx model database: the one source of truth of the schema (current schema version 4).
--
-- surfidx.db.catalog creates a new database by executing this file in one transaction and then
-- setting PRAGMA user_version to surfidx.db.catalog.SCHEMA_VERSION and PRAGMA application_id to
-- surfidx.db.catalog.APPLICATION_ID (the bytes SFDX, the mark of a surfidx file: it is checked
-- before anything is written to a file, and set on the next write in files made before it
-- existed). Older databases are brought here by the migration functions in surfidx/database.py
-- (MIGRATIONS), which must produce the same tables as this file. This file is package data
-- (what an installed surfidx reads); data_schema/schema.sql is a link to it.
--
-- Plain tables with readable column names, foreign keys and indexes, so that the file can be
-- browsed as it is with sqlite-utils or Datasette. Times are ISO 8601 UTC text, JSON is text,
-- descriptor vectors are float32 little-endian BLOBs. Names and paths from file names are stored
-- through surfidx.db.catalog.escape_name (a byte that is not UTF-8 as a backslash, x and two hex
-- digits, lossless). Statements must not contain semicolons inside comments or strings (the file
-- is split on statement boundaries).
--
-- Deleting a model row removes its asset, descriptors, thumbnail, tags, topology record and
-- original files (and a blob when no row refers to it any more), and deleting a run its error
-- records, whatever the client: the foreign keys cascade where PRAGMA foreign_keys is
-- on, and the AFTER DELETE triggers below do it where it is off (the sqlite3 shell's and
-- sqlite-utils' default). Views join the model's name to its asset and thumbnail for browsing
-- (datasette surfidx.db --metadata datasette.json shows the thumbnails as images with the
-- datasette-render-images plugin).

-- Key/value facts about the database itself: schema_version, created_by, created_at.
CREATE TABLE meta (
    key   TEXT PRIMARY KEY,
    value TEXT NOT NULL
);

-- One row per model version: what was read, how it was processed and by what. A model is a
-- name with versions 1, 2, ...: re-ingesting a changed file from the same absolute path (or
-- ingest --replace NAME) stores the next version under the same name, and a command given NAME
-- uses its latest version (NAME@N names one). The id names one version.
CREATE TABLE models (
    id           INTEGER PRIMARY KEY,
    name         TEXT    NOT NULL,                      -- file stem, else see below
    source       TEXT    NOT NULL,                      -- path relative to the ingest root
    content_hash TEXT    NOT NULL,                      -- SHA-256 hex of file (+ texture) bytes
    n_surfels    INTEGER NOT NULL CHECK (n_surfels >= 0),
    has_color    INTEGER NOT NULL CHECK (has_color IN (0, 1)),
    bbox_min_x   REAL    NOT NULL,
    bbox_min_y   REAL    NOT NULL,
    bbox_min_z   REAL    NOT NULL,
    bbox_max_x   REAL    NOT NULL,
    bbox_max_y   REAL    NOT NULL,
    bbox_max_z   REAL    NOT NULL,
    ingested_at  TEXT    NOT NULL,                      -- ISO 8601 UTC
    params       TEXT    NOT NULL DEFAULT '{}',         -- JSON: options used, codec reports...
    version      INTEGER NOT NULL DEFAULT 1 CHECK (version >= 1),
    source_abs   TEXT,                                  -- absolute path, NULL: not from a file
    source_bytes INTEGER CHECK (source_bytes >= 0),     -- size of the file, NULL if unknown
    source_mtime TEXT,                                  -- its modification time, ISO 8601 UTC
    surfidx_version    TEXT,                            -- the surfidx release that made it
    codec_version      INTEGER,                         -- container format of the stream
    descriptor_version INTEGER,                         -- descriptors' convention version
    numerics_profile   TEXT                             -- surfidx.numerics profile of the run
);
CREATE UNIQUE INDEX models_content_hash ON models (content_hash);
-- A name and version are unique: a new model whose file stem is taken is named after its
-- parent folder, and when that is taken too, STEM-2, STEM-3, ... (surfidx.db.catalog.Catalog.add).
CREATE UNIQUE INDEX models_name_version ON models (name, version);
CREATE INDEX models_source_abs ON models (source_abs);
-- The rows that may be superseded (a query widens its search by their count).
CREATE INDEX models_later_versions ON models (version) WHERE version > 1;

-- The compressed asset of a model: one container file holding the embedded bitstream, and its
-- size and quality at its full rate.
CREATE TABLE assets (
    model_id        INTEGER PRIMARY KEY REFERENCES models (id) ON DELETE CASCADE,
    stream          BLOB    NOT NULL,                   -- complete container file
    format_version  INTEGER NOT NULL,                   -- container format version of stream
    bits_per_surfel REAL    NOT NULL,                   -- full rate: 8 * bytes / n_surfels
    bytes           INTEGER NOT NULL CHECK (bytes >= 0),
    psnr_d1         REAL,                               -- dB at full rate, NULL if unknown
    psnr_d2         REAL,
    psnr_y          REAL                                -- NULL without colour
);

-- Descriptor vectors by kind (shape, texture, spectrum, ...), one row per model and kind.
CREATE TABLE descriptors (
    model_id   INTEGER NOT NULL REFERENCES models (id) ON DELETE CASCADE,
    kind       TEXT    NOT NULL,
    dimension  INTEGER NOT NULL CHECK (dimension >= 0),
    vector     BLOB    NOT NULL,                        -- dimension float32 little-endian
    convention TEXT    NOT NULL DEFAULT '{}',           -- JSON: models.params -> descriptors
    PRIMARY KEY (model_id, kind)
);
CREATE INDEX descriptors_kind ON descriptors (kind);

-- What topology repair added before mapping (surfidx.io.read_model): one row per model that
-- was not one closed genus-0 piece as read (holes, handles, pinched vertices, several pieces),
-- none for a model stored as it was. virtual_area_share: virtual faces' area over the closed
-- parts' area. details: JSON of surfidx.io.Model.summary() (genus per part, flipped faces...).
CREATE TABLE model_topology (
    model_id           INTEGER PRIMARY KEY REFERENCES models (id) ON DELETE CASCADE,
    parts              INTEGER NOT NULL CHECK (parts >= 1),
    parts_dropped      INTEGER NOT NULL DEFAULT 0 CHECK (parts_dropped >= 0),
    holes_filled       INTEGER NOT NULL DEFAULT 0 CHECK (holes_filled >= 0),
    handles_cut        INTEGER NOT NULL DEFAULT 0 CHECK (handles_cut >= 0),
    pinched_vertices   INTEGER NOT NULL DEFAULT 0 CHECK (pinched_vertices >= 0),
    virtual_surfels    INTEGER NOT NULL DEFAULT 0 CHECK (virtual_surfels >= 0),
    virtual_area_share REAL    NOT NULL DEFAULT 0
                       CHECK (virtual_area_share >= 0 AND virtual_area_share <= 1),
    details            TEXT    NOT NULL DEFAULT '{}'
);

-- A PNG picture of the decoded model.
CREATE TABLE thumbnails (
    model_id INTEGER PRIMARY KEY REFERENCES models (id) ON DELETE CASCADE,
    png      BLOB NOT NULL
);

-- Bulk ingestion runs (surfidx ingest), for bookkeeping and resuming.
CREATE TABLE ingest_runs (
    id              INTEGER PRIMARY KEY,
    started_at      TEXT    NOT NULL,
    finished_at     TEXT,                               -- NULL while running or if killed
    paths           TEXT    NOT NULL DEFAULT '[]',      -- JSON list of the paths given
    workers         INTEGER NOT NULL DEFAULT 1,
    bits_per_surfel REAL,
    stored          INTEGER NOT NULL DEFAULT 0,
    skipped         INTEGER NOT NULL DEFAULT 0,
    failed          INTEGER NOT NULL DEFAULT 0,
    status          TEXT    NOT NULL DEFAULT 'running'
                    CHECK (status IN ('running', 'finished', 'interrupted', 'failed'))
);

-- Files a run could not store, with the error message (files that are not regular files, such
-- as FIFOs or links to devices, are recorded too, with a message starting "skipped: ").
CREATE TABLE ingest_errors (
    id     INTEGER PRIMARY KEY,
    run_id INTEGER NOT NULL REFERENCES ingest_runs (id) ON DELETE CASCADE,
    path   TEXT    NOT NULL,
    error  TEXT    NOT NULL,
    at     TEXT    NOT NULL                             -- ISO 8601 UTC
);
CREATE INDEX ingest_errors_run_id ON ingest_errors (run_id);

-- Free-form labels of models (surfidx tag / untag, ingest --tag), one row per model and tag.
CREATE TABLE tags (
    model_id INTEGER NOT NULL REFERENCES models (id) ON DELETE CASCADE,
    tag      TEXT    NOT NULL CHECK (length(tag) > 0),
    PRIMARY KEY (model_id, tag)
);
CREATE INDEX tags_tag ON tags (tag);

-- Original files kept by ingest --keep-original, one row per distinct content (SHA-256 hex),
-- shared by every model version that holds it. A blob nothing refers to is deleted.
CREATE TABLE blobs (
    sha256 TEXT    PRIMARY KEY CHECK (length(sha256) = 64),
    bytes  INTEGER NOT NULL CHECK (bytes >= 0),
    data   BLOB    NOT NULL
);

-- The original files of a model version: its source file (role 'source') and the files it
-- references (role 'companion': material libraries, textures, glTF buffers), by their path
-- relative to the folder holding them all, so that written back together the model opens.
CREATE TABLE original_files (
    model_id INTEGER NOT NULL REFERENCES models (id) ON DELETE CASCADE,
    path     TEXT    NOT NULL CHECK (length(path) > 0),
    role     TEXT    NOT NULL CHECK (role IN ('source', 'companion')),
    sha256   TEXT    NOT NULL REFERENCES blobs (sha256),
    PRIMARY KEY (model_id, path)
);
CREATE INDEX original_files_sha256 ON original_files (sha256);

-- A model's rows go with it, whether the client enforces foreign keys or not.
CREATE TRIGGER models_delete_rows AFTER DELETE ON models
BEGIN
    DELETE FROM assets WHERE model_id = OLD.id;
    DELETE FROM descriptors WHERE model_id = OLD.id;
    DELETE FROM thumbnails WHERE model_id = OLD.id;
    DELETE FROM tags WHERE model_id = OLD.id;
    DELETE FROM model_topology WHERE model_id = OLD.id;
    DELETE FROM original_files WHERE model_id = OLD.id;
END;

CREATE TRIGGER original_files_delete_blob AFTER DELETE ON original_files
WHEN NOT EXISTS (SELECT 1 FROM original_files WHERE sha256 = OLD.sha256)
BEGIN
    DELETE FROM blobs WHERE sha256 = OLD.sha256;
END;

CREATE TRIGGER ingest_runs_delete_errors AFTER DELETE ON ingest_runs
BEGIN
    DELETE FROM ingest_errors WHERE run_id = OLD.id;
END;

-- Browsing: every model with its tags, figures and thumbnail, and the assets and thumbnails
-- with their model's name.
CREATE VIEW model_gallery AS
SELECT m.id, m.name, t.png AS thumbnail,
       (SELECT group_concat(tag, ', ') FROM (SELECT tag FROM tags WHERE model_id = m.id
                                             ORDER BY tag)) AS tags,
       m.n_surfels, m.has_color, a.bytes, a.bits_per_surfel, a.psnr_d1, a.psnr_y, m.source,
       m.ingested_at, m.version, m.source_abs,
       EXISTS (SELECT 1 FROM original_files WHERE model_id = m.id) AS has_original
FROM models m LEFT JOIN assets a ON a.model_id = m.id LEFT JOIN thumbnails t ON t.model_id = m.id;

CREATE VIEW assets_named AS
SELECT a.model_id, m.name, a.format_version, a.bits_per_surfel, a.bytes, a.psnr_d1, a.psnr_d2,
       a.psnr_y
FROM assets a JOIN models m ON m.id = a.model_id;

CREATE VIEW thumbnails_named AS
SELECT t.model_id, m.name, t.png
FROM thumbnails t JOIN models m ON m.id = t.model_id;
