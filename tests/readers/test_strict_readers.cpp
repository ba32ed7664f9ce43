// Strict readers (issue 11 item 4, docs/reliability.md "Strict readers"): every
// data reader against every defect class — a record cut short, extra fields,
// a field that is not a number, NaN and infinity, time going backwards, a
// repeated time stamp, a missing file — each an error naming file and line
// or, where the source has on_malformed: skip, a counted skip that keeps the
// good records. One test per reader and defect class (the matrix of
// docs/reliability.md); corrupt images and finiteness of the YAML
// descriptions follow.
#include <gtest/gtest.h>

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <functional>
#include <opencv2/imgcodecs.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "build_path.hpp"
#include "carmen_log/carmen_log.hpp"
#include "carmen_log/carmen_reader.hpp"
#include "image_sequence/image_sequence.hpp"
#include "image_sequence/read_grey.hpp"
#include "relations.hpp"
#include "victoria_park/victoria_park.hpp"

namespace mspace {
namespace {

namespace fs = std::filesystem;

fs::path scratch_dir() {
  const fs::path dir = fs::path(MSPACE_BINARY_DIR) / "test_tmp" / "readers" / std::to_string(::getpid());
  fs::create_directories(dir);
  return dir;
}

void write_file(const fs::path& path, const std::string& text) { std::ofstream(path) << text; }

/// The message of the std::runtime_error `read` throws, or "(no error)".
template <class F>
std::string error_of(F&& read) {
  try {
    read();
  } catch (const std::runtime_error& e) {
    return e.what();
  }
  return "(no error)";
}

std::string join(const std::vector<std::string>& fields, char separator) {
  std::string out;
  for (std::size_t i = 0; i < fields.size(); ++i) out += (i > 0 ? std::string(1, separator) : "") + fields[i];
  return out;
}

/// What a reader made of a file: its records, and the malformed ones it skipped.
struct Outcome {
  std::size_t records = 0;
  std::size_t skipped = 0;
};

/// One data reader: how its records look and how it is called.
struct Reader {
  std::string name;          ///< test name part
  std::string file_name;     ///< the file it reads
  char separator = ' ';
  /// The fields of a good record at time t (t = 1, 2, 3 in the good file).
  std::function<std::vector<std::string>(double t)> record;
  int number_field = 0;      ///< a numeric field to spoil (non-numeric, NaN, inf)
  bool timed = true;         ///< records must increase in time
  bool repeats_allowed = false;  ///< a repeated time stamp is not a defect (see note)
  bool can_skip = false;     ///< has on_malformed: skip
  /// Reads `file` (skip: on_malformed: skip); throws on a malformed record.
  std::function<Outcome(const fs::path& file, bool skip)> read;
};

std::string text(double t) {
  std::ostringstream s;
  s << t;
  return s.str();
}

carmen_log::ReaderOptions carmen_options(bool skip) {
  carmen_log::ReaderOptions o;
  o.skip_malformed = skip;
  return o;
}

Outcome carmen_outcome(const carmen_log::LogContents& log) { return {log.scans.size(), log.skipped}; }

/// image_sequence's laser.yaml for 3 beams, beside `csv`.
fs::path laser_yaml_beside(const fs::path& csv) {
  const fs::path yaml = csv.parent_path() / "laser.yaml";
  write_file(yaml, "beams: 3\nfirst_bearing_deg: -10\nbearing_step_deg: 10\nmax_range: 8\nmount: [0, 0, 0, 0, 0, 0]\n");
  return yaml;
}

std::vector<Reader> readers() {
  std::vector<Reader> r;
  r.push_back({"CarmenFlaser", "log.clf", ' ',
               [](double t) {
                 return std::vector<std::string>{"FLASER", "4", "1", "1.5", "2", "2.5", "0", "0", "0",
                                                 "0",      "0", "0", text(t), "host", text(t)};
               },
               3, true, false, true,
               [](const fs::path& f, bool skip) { return carmen_outcome(carmen_log::read_log(f, carmen_options(skip))); }});
  r.push_back({"IntelTable", "table.txt", ' ',
               [](double t) {
                 return std::vector<std::string>{text(t), "0", "0", "0", "0", "0", "0", "1", "1.5", "2", "2.5"};
               },
               8, true, false, true,
               [](const fs::path& f, bool skip) { return carmen_outcome(carmen_log::read_log(f, carmen_options(skip))); }});
  r.push_back({"CarmenGroundTruthTum", "truth.tum", ' ',
               [](double t) { return std::vector<std::string>{text(t), "1", "2", "0", "0", "0", "0", "1"}; }, 7, true,
               false, false, [](const fs::path& f, bool) {
                 // The log the ground truth is for: scans at t = 1 … 3.
                 const fs::path log = f.parent_path() / "gt_log.txt";
                 write_file(log, "1 0 0 0 0 0 0 1 1\n2 0 0 0 0 0 0 1 1\n3 0 0 0 0 0 0 1 1\n");
                 PluginArgs a;
                 a.instance_name = "source";
                 a.params = Params::defaults(carmen_log::CarmenLogSource::param_specs());
                 a.params.set("file", log.string());
                 a.params.set("ground_truth", f.string());
                 const carmen_log::CarmenLogSource source(a);
                 return Outcome{source.size_hint(), source.skipped_records()};
               }});
  r.push_back({"VictoriaParkDeadReckoning", "aa3_dr.txt", ' ',
               [](double t) { return std::vector<std::string>{text(21000 + 25 * t), "1.5", "0.1"}; }, 2, true, false,
               true, [](const fs::path& f, bool skip) {
                 records::MalformedRecords m(skip ? "skip" : "error");
                 const std::size_t n = victoria_park::read_dead_reckoning(f, m).size();
                 return Outcome{n, m.skipped()};
               }});
  r.push_back({"VictoriaParkGps", "aa3_gpsx.txt", ' ',
               [](double t) { return std::vector<std::string>{text(21000 + 200 * t), "5.5", "-3"}; }, 2, true, false,
               false, [](const fs::path& f, bool) { return Outcome{victoria_park::read_gps(f).size(), 0}; }});
  // Consecutive detections with one time stamp are the trunks of one scan:
  // a repeated stamp is the format, not a defect.
  r.push_back({"VictoriaParkDetections", "measurements.dat", ' ',
               [](double t) { return std::vector<std::string>{text(t), "10.5", "1.5", "0.3"}; }, 3, true, true, true,
               [](const fs::path& f, bool skip) {
                 records::MalformedRecords m(skip ? "skip" : "error");
                 const std::size_t n = victoria_park::read_detections(f, m).size();
                 return Outcome{n, m.skipped()};
               }});
  r.push_back({"ImageSequenceFrames", "frames.csv", ',',
               [](double t) { return std::vector<std::string>{text(t), "images/" + text(t) + ".png"}; }, 0, true, false,
               true, [](const fs::path& f, bool skip) {
                 records::MalformedRecords m(skip ? "skip" : "error");
                 const std::size_t n = image_sequence::read_frames_csv(f.string(), f.parent_path().string(), m).size();
                 return Outcome{n, m.skipped()};
               }});
  r.push_back({"ImageSequenceOdometry", "odometry.csv", ',',
               [](double t) { return std::vector<std::string>{text(t), "0.5", "1", "0.25"}; }, 3, true, false, true,
               [](const fs::path& f, bool skip) {
                 records::MalformedRecords m(skip ? "skip" : "error");
                 const std::size_t n = image_sequence::read_odometry_csv(f.string(), m).size();
                 return Outcome{n, m.skipped()};
               }});
  r.push_back({"ImageSequenceLaser", "laser.csv", ',',
               [](double t) { return std::vector<std::string>{text(t), "1", "2.5", "0"}; }, 2, true, false, true,
               [](const fs::path& f, bool skip) {
                 records::MalformedRecords m(skip ? "skip" : "error");
                 const std::size_t n =
                     image_sequence::read_laser(laser_yaml_beside(f).string(), f.string(), m).t.size();
                 return Outcome{n, m.skipped()};
               }});
  r.push_back({"ImageSequenceGroundTruth", "groundtruth.tum", ' ',
               [](double t) { return std::vector<std::string>{text(t), "1", "2", "0", "0", "0", "0", "1"}; }, 1, true,
               false, false,
               [](const fs::path& f, bool) { return Outcome{image_sequence::read_tum(f.string()).size(), 0}; }});
  // Relations pair two times each and need no order.
  r.push_back({"Relations", "intel.relations", ' ',
               [](double t) { return std::vector<std::string>{text(t), text(t + 5), "0.5", "0", "0", "0", "0", "0.1"}; },
               7, false, false, false,
               [](const fs::path& f, bool) { return Outcome{kernel::read_relations(f).size(), 0}; }});
  return r;
}

enum class Defect { Truncated, ExtraField, NonNumeric, NaN, Infinity, Backwards, Repeated, MissingFile };

const char* defect_name(Defect d) {
  switch (d) {
    case Defect::Truncated: return "Truncated";
    case Defect::ExtraField: return "ExtraField";
    case Defect::NonNumeric: return "NonNumeric";
    case Defect::NaN: return "NaN";
    case Defect::Infinity: return "Infinity";
    case Defect::Backwards: return "TimeGoesBackwards";
    case Defect::Repeated: return "RepeatedTimeStamp";
    case Defect::MissingFile: return "MissingFile";
  }
  return "?";
}

/// The bad record of a defect: the good record at t = 2.5 spoilt (or, for the
/// time defects, a good record at an earlier or the previous time).
std::string bad_record(const Reader& r, Defect d) {
  std::vector<std::string> f = r.record(2.5);
  switch (d) {
    case Defect::Truncated: f.resize(f.size() / 2); break;
    case Defect::ExtraField: f.push_back("7"); break;
    case Defect::NonNumeric: f[static_cast<std::size_t>(r.number_field)] = "x1"; break;
    case Defect::NaN: f[static_cast<std::size_t>(r.number_field)] = "nan"; break;
    case Defect::Infinity: f[static_cast<std::size_t>(r.number_field)] = "inf"; break;
    case Defect::Backwards: f = r.record(1.5); break;
    case Defect::Repeated: f = r.record(2); break;
    case Defect::MissingFile: break;
  }
  return join(f, r.separator);
}

struct Case {
  std::size_t reader = 0;
  Defect defect = Defect::Truncated;
};

std::vector<Case> all_cases() {
  std::vector<Case> out;
  const std::vector<Reader> rs = readers();
  for (std::size_t i = 0; i < rs.size(); ++i)
    for (Defect d : {Defect::Truncated, Defect::ExtraField, Defect::NonNumeric, Defect::NaN, Defect::Infinity,
                     Defect::Backwards, Defect::Repeated, Defect::MissingFile}) {
      if (!rs[i].timed && (d == Defect::Backwards || d == Defect::Repeated)) continue;
      if (rs[i].repeats_allowed && d == Defect::Repeated) continue;
      out.push_back({i, d});
    }
  return out;
}

class StrictReader : public testing::TestWithParam<Case> {};

// Line 1 a comment, lines 2–3 good records (t = 1, 2), line 4 the bad one,
// line 5 a good record (t = 3).
TEST_P(StrictReader, NamesFileAndLineOrSkipsAndCounts) {
  const Reader r = readers()[GetParam().reader];
  const Defect d = GetParam().defect;
  const fs::path dir = scratch_dir() / (r.name + "_" + defect_name(d));
  fs::create_directories(dir);
  const fs::path file = dir / r.file_name;
  write_file(file, "# test file\n" + join(r.record(1), r.separator) + "\n" + join(r.record(2), r.separator) + "\n" +
                       join(r.record(3), r.separator) + "\n");
  const Outcome good = r.read(file, false);  // the file without its defect reads whole
  EXPECT_EQ(good.records, 3u);
  EXPECT_EQ(good.skipped, 0u);

  if (d == Defect::MissingFile) {
    fs::remove(file);
    const std::string error = error_of([&] { r.read(file, false); });
    EXPECT_NE(error.find(file.string()), std::string::npos) << error;
    return;
  }
  write_file(file, "# test file\n" + join(r.record(1), r.separator) + "\n" + join(r.record(2), r.separator) + "\n" +
                       bad_record(r, d) + "\n" + join(r.record(3), r.separator) + "\n");
  const std::string error = error_of([&] { r.read(file, false); });
  EXPECT_NE(error.find(file.string() + ":4: "), std::string::npos) << "bad record '" << bad_record(r, d) << "': " << error;
  if (r.can_skip) {
    const Outcome skipped = r.read(file, true);
    EXPECT_EQ(skipped.skipped, 1u);
    EXPECT_EQ(skipped.records, 3u);
  }
}

INSTANTIATE_TEST_SUITE_P(Matrix, StrictReader, testing::ValuesIn(all_cases()),
                         [](const testing::TestParamInfo<Case>& info) {
                           return readers()[info.param.reader].name + "_" + defect_name(info.param.defect);
                         });

// The messages a user reads, for a few cells of the matrix.
TEST(StrictReaders, MessagesSayWhatIsWrong) {
  const fs::path dir = scratch_dir() / "messages";
  fs::create_directories(dir);
  const fs::path clf = dir / "run.clf";
  write_file(clf,
             "FLASER 2 1 1 0 0 0 0 0 0 1 host 1\n"
             "FLASER 2 1 1 0 0 0 0 0 0 2 host 2 FLASER 2 1 1 0 0 0 0 0 0 3 host 3\n");
  const auto read_clf = [&] { carmen_log::read_log(clf, {}); };
  std::string error = error_of(read_clf);
  EXPECT_NE(error.find("run.clf:2: 13 extra field(s) after the time stamp"), std::string::npos) << error;
  write_file(clf, "FLASER 2 1 1 0 0 0 0 0 0 1 host 1\nFLASER 2 1 1 0 0 0 0 0 0 1 host 1\n");
  error = error_of(read_clf);
  EXPECT_NE(error.find("run.clf:2: time stamp 1.000000 s is that of the previous scan's 1.000000 s (line 1): a "
                       "repeated scan"),
            std::string::npos)
      << error;
  const fs::path gps = dir / "aa3_gpsx.txt";
  write_file(gps, "21000 1 2\n21200 1 2\n21200 1 3\n");
  error = error_of([&] { victoria_park::read_gps(gps); });
  EXPECT_NE(error.find("aa3_gpsx.txt:3: time 0.233000 s repeats the previous record's (line 2: 0.233000 s)"),
            std::string::npos)
      << error;
}

// The skip count reaches the run summary through DataSource::skipped_records.
TEST(StrictReaders, SourcesReportTheirSkippedRecords) {
  const fs::path dir = scratch_dir() / "skipped";
  fs::create_directories(dir);
  const fs::path table = dir / "table.txt";
  write_file(table, "1 0 0 0 0 0 0 1 1\n2 0 0 0 0 0 0 1 nan\n3 0 0 0 0 0 0 1 1\n3 0 0 0 0 0 0 1 1\n");
  PluginArgs a;
  a.instance_name = "source";
  a.params = Params::defaults(carmen_log::CarmenLogSource::param_specs());
  a.params.set("file", table.string());
  a.params.set("on_malformed", std::string("skip"));
  const carmen_log::CarmenLogSource source(a);
  EXPECT_EQ(source.size_hint(), 2u);
  EXPECT_EQ(source.skipped_records(), 2u);
}

// Descriptions are strict too: a camera.yaml or laser.yaml value that is not
// finite is named with file and line (YAML reads .nan and .inf as numbers).
TEST(StrictReaders, YamlDescriptionsMustBeFinite) {
  const fs::path dir = scratch_dir() / "yaml";
  fs::create_directories(dir);
  const fs::path camera = dir / "camera.yaml";
  write_file(camera,
             "width: 320\nheight: 240\nfx: 260\nfy: 260\ncx: .nan\ncy: 120\n"
             "distortion: [0, 0, 0, 0, 0]\nmount: [0, 0, 0, 0, 0, 0]\n");
  const auto read_camera = [&] { image_sequence::read_camera_yaml(camera.string()); };
  EXPECT_EQ(error_of(read_camera), camera.string() + ":5: key 'cx' is not a finite number");
  write_file(camera,
             "width: 320\nheight: 240\nfx: 260\nfy: 260\ncx: 160\ncy: 120\n"
             "distortion: [0, 0, 0, 0, 0]\nmount: [0, 0, .inf, 0, 0, 0]\n");
  EXPECT_EQ(error_of(read_camera), camera.string() + ":8: 'mount' holds a value that is not finite");
}

// A corrupt image: a PNG cut short passes the check of its signature when the
// source is built, and is an error naming the file when it is read.
TEST(StrictReaders, TruncatedImageIsAnErrorNamingTheFile) {
  const fs::path dir = scratch_dir() / "image";
  fs::create_directories(dir);
  const fs::path png = dir / "frame.png";
  cv::Mat image(48, 64, CV_8UC1);
  cv::randu(image, 0, 255);
  ASSERT_TRUE(cv::imwrite(png.string(), image));
  ASSERT_TRUE(cv::haveImageReader(png.string()));
  camera::CameraModel model;
  model.width = 64;
  model.height = 48;
  SensorReading reading;
  reading.channel = "camera";
  reading.file = png.string();
  EXPECT_EQ(camera::read_grey(reading, model).cols, 64);
  fs::resize_file(png, fs::file_size(png) / 2);
  EXPECT_TRUE(cv::haveImageReader(png.string()));  // the signature is still there
  EXPECT_EQ(error_of([&] { camera::read_grey(reading, model); }), png.string() + ": cannot read image");
}

}  // namespace
}  // namespace mspace
