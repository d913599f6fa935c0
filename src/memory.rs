//! Memory estimates: a render's large allocations sized before any is
//! made ([`MemoryItem`], each method's estimate in its folder, see
//! [`crate::methods::MethodConfig::memory`]), and the check that refuses a
//! render past a limit, naming what is too large ([`check_memory`]): a
//! failed allocation would abort the process instead of reporting.

/// One large allocation of a render, estimated before it is made.
#[derive(Clone, Debug, PartialEq)]
pub struct MemoryItem {
    /// What it is, in the user's terms ("the film 512×512 (8 lanes)").
    pub what: String,
    /// Its estimated size in bytes.
    pub bytes: u64,
    /// How to make it smaller ("lower --res").
    pub remedy: &'static str,
}

/// A render that would need more memory than its limit.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error(
    "{what} needs {}{}; the limit is {} ({source_of_limit}): {remedy} or raise --max-memory",
    format_bytes(*bytes),
    total_note(*bytes, *total),
    format_bytes(*limit)
)]
pub struct MemoryError {
    /// The largest item ([`MemoryItem::what`]).
    pub what: String,
    /// Its estimate in bytes.
    pub bytes: u64,
    /// The estimate of all items together.
    pub total: u64,
    /// The limit in bytes.
    pub limit: u64,
    /// Where the limit comes from ("this machine's memory").
    pub source_of_limit: String,
    /// How to make the largest item smaller.
    pub remedy: &'static str,
}

/// " (the render 10.0 GB in all)" when the total reads differently from
/// the largest item's figure, else nothing.
fn total_note(bytes: u64, total: u64) -> String {
    let t = format_bytes(total);
    if t == format_bytes(bytes) {
        String::new()
    } else {
        format!(" (the render {t} in all)")
    }
}

/// Bytes as the user reads them: decimal units with one decimal, "51.5 GB".
pub fn format_bytes(bytes: u64) -> String {
    let b = bytes as f64;
    for (unit, size) in [("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)] {
        if b >= size {
            return format!("{:.1} {unit}", b / size);
        }
    }
    format!("{bytes} B")
}

/// Refuses `items` when they need more than `limit` bytes together: the
/// error names the largest item, its estimate, the total when there are
/// several, and the limit with where it comes from (`source_of_limit`).
pub fn check_memory(
    items: &[MemoryItem],
    limit: u64,
    source_of_limit: &str,
) -> Result<(), MemoryError> {
    let total = items.iter().fold(0u64, |t, i| t.saturating_add(i.bytes));
    if total <= limit {
        return Ok(());
    }
    let largest = items
        .iter()
        .max_by_key(|i| i.bytes)
        .expect("a total above the limit has at least one item");
    Err(MemoryError {
        what: largest.what.clone(),
        bytes: largest.bytes,
        total,
        limit,
        source_of_limit: source_of_limit.to_string(),
        remedy: largest.remedy,
    })
}
