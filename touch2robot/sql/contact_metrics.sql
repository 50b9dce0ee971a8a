-- Contact-agreement metrics as DuckDB macros over a table or view named `contacts`
-- (columns as schemas.tables.contacts; e.g. read_parquet('<lake>/contacts/**/*.parquet',
-- hive_partitioning = true)). Loaded by touch2robot.metrics.register_contact_macros(con);
-- the `contacts` view must exist before loading (DuckDB binds table macros on creation).
--
-- ALIGNMENT RULE (identical to touch2robot.metrics.align_to_reference): an evaluated sample at
-- reference time t_ref is compared with the reference sample of the same (reference_id, region)
-- with the greatest t_ref <= the evaluated t_ref (backward ASOF JOIN, exact matches allowed).
-- Evaluated samples before the first reference sample, or whose reference_id has no reference
-- rows, are dropped (the ASOF JOIN is inner). The reference source must hold one sequence per
-- reference_id (true for 'human'); to use e.g. 'sim' as the reference, restrict the view to one
-- method first. method/task/subject of a compared pair are those of the evaluated row.
--
-- UNDEFINED RATIOS: a score whose denominator is 0 is NULL (pandas reads it back as NaN, which
-- is what the Python functions return). Counts are BIGINT.
--
-- Usage:
--   SELECT * FROM contact_counts('human', 'sim');            -- per method, task, subject, region
--   SELECT * FROM contact_score_slices('human', 'real')       -- every slice, '*' = all
--    WHERE task = 'pick' AND subject = '*' AND region = '*';
--   SELECT method, region, contact_f1(sum(tp), sum(fp), sum(fn)) AS f1  -- any custom slice
--     FROM contact_counts('human', 'sim') WHERE task IN ('pick', 'wipe') GROUP BY ALL;

CREATE OR REPLACE MACRO contact_ratio(num, den) AS
    CASE WHEN den = 0 THEN NULL ELSE num::DOUBLE / den::DOUBLE END;
CREATE OR REPLACE MACRO contact_precision(tp, fp) AS contact_ratio(tp, tp + fp);
CREATE OR REPLACE MACRO contact_recall(tp, fn) AS contact_ratio(tp, tp + fn);
CREATE OR REPLACE MACRO contact_f1(tp, fp, fn) AS contact_ratio(2 * tp, 2 * tp + fp + fn);
CREATE OR REPLACE MACRO contact_fpr(fp, tn) AS contact_ratio(fp, fp + tn);

-- One row per kept evaluated sample with the reference sample it is compared with.
CREATE OR REPLACE MACRO contact_pairs(ref_source, eval_source) AS TABLE
    SELECT e.method, e.task, e.subject, e.region, e.sequence_id, e.reference_id,
           e.t, e.t_ref, r.t_ref AS ref_t_ref,
           r.contact AS ref_contact, e.contact AS eval_contact
    FROM (SELECT * FROM contacts WHERE source = eval_source) AS e
    ASOF JOIN (
        SELECT reference_id, region, t_ref, contact FROM contacts WHERE source = ref_source
    ) AS r
      ON e.reference_id = r.reference_id
     AND e.region = r.region
     AND e.t_ref >= r.t_ref;

-- TP/FP/FN/TN per (method, task, subject, region); contact is the positive class.
CREATE OR REPLACE MACRO contact_counts(ref_source, eval_source) AS TABLE
    SELECT method, task, subject, region,
           count_if(ref_contact AND eval_contact)::BIGINT AS tp,
           count_if(NOT ref_contact AND eval_contact)::BIGINT AS fp,
           count_if(ref_contact AND NOT eval_contact)::BIGINT AS fn,
           count_if(NOT ref_contact AND NOT eval_contact)::BIGINT AS tn
    FROM contact_pairs(ref_source, eval_source)
    GROUP BY method, task, subject, region
    ORDER BY method, task, subject, region;

-- Counts and scores per method for every combination of task/subject/region slices;
-- a rolled-up dimension reads '*' (all tasks / subjects / regions).
CREATE OR REPLACE MACRO contact_score_slices(ref_source, eval_source) AS TABLE
    WITH summed AS (
        SELECT method,
               CASE WHEN grouping(task) = 1 THEN '*' ELSE task END AS task,
               CASE WHEN grouping(subject) = 1 THEN '*' ELSE subject END AS subject,
               CASE WHEN grouping(region) = 1 THEN '*' ELSE region END AS region,
               sum(tp)::BIGINT AS tp, sum(fp)::BIGINT AS fp,
               sum(fn)::BIGINT AS fn, sum(tn)::BIGINT AS tn
        FROM contact_counts(ref_source, eval_source)
        GROUP BY method, CUBE (task, subject, region)
    )
    SELECT method, task, subject, region, tp, fp, fn, tn,
           contact_precision(tp, fp) AS precision,
           contact_recall(tp, fn) AS recall,
           contact_f1(tp, fp, fn) AS f1,
           contact_fpr(fp, tn) AS fpr
    FROM summed
    ORDER BY method, task, subject, region;
