// meshflow engine — small filesystem helpers with the atomicity the cache relies on.
#pragma once

#include <filesystem>
#include <string>
#include <string_view>

namespace meshflow {

// Writes `bytes` to `target` atomically: a unique temp file in the same directory, fsync,
// rename over the target. Readers see the old file or the whole new one, never a part.
// The temp file lives in `tmp_dir` (same filesystem as the target) when given, so that a
// process killed mid-write leaves its debris only where the cache's cleanup looks.
// `durable` adds an fsync before the rename (survives power loss, costs milliseconds); a
// killed process never leaves a partial file either way.
void atomic_write(const std::filesystem::path& target, std::string_view bytes,
                  const std::filesystem::path& tmp_dir = {}, bool durable = true);
std::string read_file(const std::filesystem::path& file);  // throws naming the file
// Creates `target` (which must not exist) as an independent copy of `source`: a reflink
// (FICLONE: shared blocks, copy on write) where the filesystem has them, else a byte copy.
// Never a hard link: writing to the copy cannot change the source. Mode 0644. Throws.
void clone_or_copy(const std::filesystem::path& source, const std::filesystem::path& target);
// Removes the temp files ("*.tmp.<host>_<pid>_...") that dead processes of this host left in
// `dir` (not recursive), and any older than a day. Returns how many.
int remove_stale_tmp_files(const std::filesystem::path& dir);
// True when `dir` exists or can be created and a file can be created in it; else false with
// the reason in `why`.
bool writable_dir(const std::filesystem::path& dir, std::string* why);
std::string hostname();
bool process_alive(long pid);  // on this host
// A name unique to this process and call: <host>_<pid>_<counter>_<random>, host sanitised to
// [A-Za-z0-9]. parse_owner() recovers host and pid so debris of dead processes can be removed.
std::string unique_suffix();
bool parse_owner(const std::string& name, std::string* host, long* pid);
std::string sanitized_hostname();
// Debris: the temp file or folder `p`, whose owner part of the name is `owner_name`
// (<host>_<pid>_..., see unique_suffix), was left by a dead process of this host, or is older
// than a day (another host's, or a name without an owner).
bool stale_debris(const std::filesystem::path& p, const std::string& owner_name);

}  // namespace meshflow
