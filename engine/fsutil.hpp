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
std::string hostname();
bool process_alive(long pid);  // on this host
// A name unique to this process and call: <host>_<pid>_<counter>_<random>, host sanitised to
// [A-Za-z0-9]. parse_owner() recovers host and pid so debris of dead processes can be removed.
std::string unique_suffix();
bool parse_owner(const std::string& name, std::string* host, long* pid);
std::string sanitized_hostname();

}  // namespace meshflow
