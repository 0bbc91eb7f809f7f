// Job: the HuMem ORB-SLAM3 plugin (see VprKeyFrameDatabase.h): settings,
// factory registration, keyframe/frame hooks, loop/merge and relocalisation
// candidates from HuMem, and the store's maintenance (erase, resets, poses).
#include "VprKeyFrameDatabase.h"

#include <cstdlib>

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <ctime>
#include <iomanip>
#include <iostream>
#include <set>
#include <sstream>

#include <opencv2/core/core.hpp>
#include <opencv2/imgproc/imgproc.hpp>

#include "Frame.h"
#include "KeyFrame.h"
#include "Map.h"

namespace ORB_SLAM3
{

namespace
{

// Registers the factory when libORB_SLAM3 is loaded (this file is compiled
// into it, so the object is always linked).
struct RegisterFactory
{
    RegisterFactory() { KeyFrameDatabase::SetFactory(&VprKeyFrameDatabase::Create); }
} gRegisterFactory;

std::atomic<uint64_t> gWriteFailures(0);

bool ReadString(const cv::FileStorage &fs, const char* key, std::string* out)
{
    cv::FileNode node = fs[key];
    if(node.empty())
        return false;
    if(node.isString())
        *out = node.string();
    else if(node.isInt())
        *out = std::to_string(static_cast<int>(node));
    else
        return false;
    return true;
}

template <typename T>
bool ReadNumber(const cv::FileStorage &fs, const char* key, T* out)
{
    cv::FileNode node = fs[key];
    if(node.empty())
        return false;
    if(node.isInt())
        *out = static_cast<T>(static_cast<int>(node));
    else if(node.isReal())
        *out = static_cast<T>(static_cast<double>(node));
    else
        return false;
    return true;
}

bool ReadBool(const cv::FileStorage &fs, const char* key, bool* out)
{
    int v = 0;
    if(!ReadNumber(fs, key, &v))
        return false;
    *out = v != 0;
    return true;
}

std::string DefaultSessionId()
{
    char buf[32];
    time_t now = time(0);
    struct tm t;
    gmtime_r(&now, &t);
    strftime(buf, sizeof(buf), "%Y%m%dT%H%M%SZ", &t);
    std::ostringstream s;
    s << buf << "-" << getpid();
    return s.str();
}

humem::Pose PoseOf(KeyFrame* pKF, float* Twc34 = 0)
{
    // T_wc (camera to world) as HuMem's Pose wants it: camera centre + orientation in the map.
    Eigen::Matrix4f Twc = pKF->GetPoseInverse().matrix();
    if(Twc34)
        for(int r = 0; r < 3; ++r)
            for(int c = 0; c < 4; ++c)
                Twc34[r * 4 + c] = Twc(r, c);
    return humem::Pose::FromMatrixColumnMajor(Twc.data());
}

// Whether two 3x4 poses differ at all (beyond float noise).
bool PoseChanged(const float* a, const float* b)
{
    for(int i = 0; i < 12; ++i)
        if(std::fabs(a[i] - b[i]) > 1e-6f)
            return true;
    return false;
}

// A pose as the sent log writes it: tx ty tz qx qy qz qw (TUM order).
std::string PoseText(const humem::Pose &p)
{
    std::ostringstream s;
    s << std::setprecision(9) << p.translation.x << " " << p.translation.y << " " << p.translation.z << " "
      << p.rotation.x << " " << p.rotation.y << " " << p.rotation.z << " " << p.rotation.w;
    return s.str();
}

double MsSince(std::chrono::steady_clock::time_point t0)
{
    return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

} // namespace

// ---------------------------------------------------------------------------
// Settings

HuMemSettings::HuMemSettings()
    : enabled(true), robotId("orbslam3"), resetSessionOnStart(false), queryDeadlineMs(500),
      queryTimeoutMs(5000), imageCacheFrames(64), topN(0), relocTopN(10), threshold(-1.f), relocThreshold(0.f),
      minFrameGap(-1), relocMinFrameGap(0), relocMaxAgeFrames(30), minMapKeyFrames(12),
      dbow2Fallback(false), poseUpdates(true), reportVerdicts(true), verifyBelowScore(0.5f), imageOrder("bgr"),
      verbose(1), sentLog()
{
}

bool HuMemSettings::Load(const std::string &strSettingsFile)
{
    cv::FileStorage fs(strSettingsFile.c_str(), cv::FileStorage::READ);
    if(!fs.isOpened())
        return false;
    ReadBool(fs, "HuMem.Enabled", &enabled);
    ReadString(fs, "HuMem.Address", &address);
    ReadString(fs, "HuMem.TlsCaFile", &tlsCaFile);
    ReadString(fs, "HuMem.TlsCertFile", &tlsCertFile);
    ReadString(fs, "HuMem.TlsKeyFile", &tlsKeyFile);
    ReadString(fs, "HuMem.TlsServerName", &tlsServerName);
    ReadString(fs, "HuMem.AuthToken", &authToken);
    // A token is a secret: the environment keeps it out of settings files.
    if(const char* token = std::getenv("HUMEM_TOKEN"))
        if(*token)
            authToken = token;
    ReadString(fs, "HuMem.RobotId", &robotId);
    ReadString(fs, "HuMem.SessionId", &sessionId);
    ReadBool(fs, "HuMem.ResetSessionOnStart", &resetSessionOnStart);
    ReadNumber(fs, "HuMem.QueryDeadlineMs", &queryDeadlineMs);
    ReadNumber(fs, "HuMem.QueryTimeoutMs", &queryTimeoutMs);
    ReadNumber(fs, "HuMem.ImageCacheFrames", &imageCacheFrames);
    ReadNumber(fs, "HuMem.TopN", &topN);
    ReadNumber(fs, "HuMem.RelocTopN", &relocTopN);
    ReadNumber(fs, "HuMem.Threshold", &threshold);
    ReadNumber(fs, "HuMem.RelocThreshold", &relocThreshold);
    ReadNumber(fs, "HuMem.MinFrameGap", &minFrameGap);
    ReadNumber(fs, "HuMem.RelocMinFrameGap", &relocMinFrameGap);
    ReadNumber(fs, "HuMem.RelocMaxAgeFrames", &relocMaxAgeFrames);
    ReadString(fs, "HuMem.Layers", &layers);
    ReadNumber(fs, "HuMem.MinMapKeyFrames", &minMapKeyFrames);
    ReadBool(fs, "HuMem.DBoW2Fallback", &dbow2Fallback);
    ReadBool(fs, "HuMem.PoseUpdates", &poseUpdates);
    ReadBool(fs, "HuMem.ReportVerdicts", &reportVerdicts);
    ReadNumber(fs, "HuMem.VerifyBelowScore", &verifyBelowScore);
    ReadString(fs, "HuMem.ImageOrder", &imageOrder);
    if(imageOrder != "bgr" && imageOrder != "rgb" && imageOrder != "gray")
    {
        std::cerr << "[HuMem] warning: HuMem.ImageOrder '" << imageOrder << "' is not bgr, rgb or gray; using bgr"
                  << std::endl;
        imageOrder = "bgr";
    }
    ReadNumber(fs, "HuMem.Verbose", &verbose);
    ReadString(fs, "HuMem.SentLog", &sentLog);
    if(imageCacheFrames < 1)
        imageCacheFrames = 1;
    if(queryDeadlineMs < 0)
        queryDeadlineMs = 0;
    return true;
}

// ---------------------------------------------------------------------------
// Factory

KeyFrameDatabase* VprKeyFrameDatabase::Create(const ORBVocabulary &voc, const std::string &strSettingsFile)
{
    HuMemSettings s;
    if(!s.Load(strSettingsFile) || !s.enabled || s.address.empty())
    {
        std::cout << "[HuMem] place recognition: DBoW2 (HuMem "
                  << (s.enabled ? "not configured: no HuMem.Address" : "disabled: HuMem.Enabled is 0")
                  << ")" << std::endl;
        return new KeyFrameDatabase(voc);
    }
    if(s.sessionId.empty())
        s.sessionId = DefaultSessionId();

    humem::ClientOptions options;
    options.target = s.address;
    options.tls_ca_file = s.tlsCaFile;
    options.tls_cert_file = s.tlsCertFile;
    options.tls_key_file = s.tlsKeyFile;
    options.tls_server_name = s.tlsServerName;
    options.auth_token = s.authToken;
    options.robot_id = s.robotId;
    options.session_id = s.sessionId;
    options.query_timeout = std::chrono::milliseconds(s.queryTimeoutMs);
    options.on_write_failed = [](const humem::WriteFailure &f) {
        ++gWriteFailures;
        std::ostringstream m;
        m << "[HuMem] warning: write #" << f.sequence << " (kind " << static_cast<int>(f.kind)
          << ", keyframe " << f.keyframe_id << ") failed: " << f.status.ToString() << "\n";
        std::cout << m.str() << std::flush;
    };
    humem::Status status;
    std::unique_ptr<humem::VprClient> client = humem::VprClient::Create(options, &status);
    if(!client)
    {
        std::cout << "[HuMem] error: cannot create the client (" << status.ToString()
                  << "); place recognition falls back to DBoW2" << std::endl;
        return new KeyFrameDatabase(voc);
    }
    return new VprKeyFrameDatabase(voc, s, std::move(client));
}

VprKeyFrameDatabase::Counters::Counters()
    : framesCached(0), keyframesSeen(0), inserts(0), insertsNoImage(0), insertsRefused(0), erases(0),
      mapResets(0), sessionResets(0), poseUpdates(0), posesSent(0), loopQueries(0), loopAnswered(0),
      loopNotAnswered(0), loopCandidates(0), loopUsed(0), mergeUsed(0), relocQueries(0),
      relocAnswersUsed(0), relocCandidates(0), writeFailures(0), verdictsReported(0), verdictsAccepted(0),
      verdictsNotHuMem(0), verdictsSkipped(0), extraCoincidences(0)
{
}

VprKeyFrameDatabase::VprKeyFrameDatabase(const ORBVocabulary &voc, const HuMemSettings &settings,
                                         std::unique_ptr<humem::VprClient> client)
    : KeyFrameDatabase(voc), mSettings(settings), mClient(std::move(client)),
      mImages(static_cast<size_t>(settings.imageCacheFrames)), mSessionId(settings.sessionId),
      mSessionResets(0), mRelocProposalFrame(0), mHaveReloc(false), mRelocFrameId(0), mRefusedInRow(0),
      mFailedQueriesInRow(0)
{
    std::ostringstream m;
    m << "place recognition: HuMem at " << mSettings.address << ", robot '" << mSettings.robotId
      << "', session '" << mSessionId << "', loop deadline " << mSettings.queryDeadlineMs
      << " ms, image cache " << mSettings.imageCacheFrames << " frames, DBoW2 fallback "
      << (mSettings.dbow2Fallback ? "on" : "off") << ", verdicts " << (mSettings.reportVerdicts ? "reported" : "not reported");
    if(mSettings.verifyBelowScore > 0.f)
        m << ", a 4th coincidence below score " << mSettings.verifyBelowScore;
    m << ", images " << (mSettings.imageOrder == "gray" ? "sent grey" : "as the camera gives them (" + mSettings.imageOrder + " if colour)");
    Log(1, m.str());
    if(!mSettings.sentLog.empty())
    {
        mSentLog.open(mSettings.sentLog.c_str(), std::ios::out | std::ios::trunc);
        if(mSentLog)
        {
            mSentLog << "# HuMem sent log: insert KF FRAME MAP TIMESTAMP POSE | pose KF MAP POSE | erase KF | "
                        "reset_map MAP | reset_session | query KF MAP; POSE = T_wc as tx ty tz qx qy qz qw\n";
            Log(1, "sent log: " + mSettings.sentLog);
        }
        else
            Log(0, "cannot open HuMem.SentLog " + mSettings.sentLog + ": nothing is recorded");
    }
    if(mSettings.resetSessionOnStart)
        mClient->ResetSession();
}

VprKeyFrameDatabase::~VprKeyFrameDatabase()
{
    // ORB-SLAM3 never deletes its database; if someone does, let queued writes drain.
    mClient->Close(std::chrono::milliseconds(2000));
}

VprKeyFrameDatabase::Counters VprKeyFrameDatabase::GetCounters()
{
    std::lock_guard<std::mutex> lock(mMutexHm);
    Counters c = mCounters;
    c.writeFailures = gWriteFailures.load();
    return c;
}

void VprKeyFrameDatabase::RecordSentLocked(const std::string &line, bool flush)
{
    if(!mSentLog.is_open())
        return;
    mSentLog << line << '\n';
    if(flush)
        mSentLog.flush();
}

void VprKeyFrameDatabase::Log(int level, const std::string &message)
{
    if(level > mSettings.verbose)
        return;
    std::lock_guard<std::mutex> lock(mMutexLog);
    std::cout << (level == 0 ? "[HuMem] warning: " : "[HuMem] ") << message << std::endl;
}

std::string VprKeyFrameDatabase::DescribeCandidate(const humem::Candidate &c) const
{
    std::ostringstream s;
    s << "KF " << c.keyframe_id << " (frame " << c.frame_id << ", map " << c.map_id << ", score "
      << std::fixed << std::setprecision(3) << c.score << ")";
    return s.str();
}

void VprKeyFrameDatabase::ApplyQueryOptions(humem::QueryRequest &q, bool reloc) const
{
    // Loop vs merge is decided here, by each keyframe's current map. ORB-SLAM3
    // v1.0 relocalises in the active map only: ask about that map, so that
    // look-alike keyframes of older maps do not crowd the answer.
    q.scope = reloc && q.map_id.has_value() ? humem::Scope::kSameMap : humem::Scope::kAllMaps;
    const int topN = reloc ? mSettings.relocTopN : mSettings.topN;
    if(topN > 0)
        q.top_n = static_cast<uint32_t>(topN);
    // Relocalisation, like DBoW2's, has no absolute score threshold by
    // default (HuMem.RelocThreshold 0): Tracking checks every candidate with
    // PnP, and a frame just after tracking was lost (motion blur, a turn)
    // scores its true places low; with the loop threshold, 63 of 64
    // relocalisation answers in a town-dev run were empty.
    float threshold = reloc && mSettings.relocThreshold >= 0.f ? mSettings.relocThreshold : mSettings.threshold;
    if(threshold >= 0.f)
        q.threshold = threshold;
    if(reloc)
        q.min_frame_gap = static_cast<uint64_t>(std::max(0, mSettings.relocMinFrameGap));
    else if(mSettings.minFrameGap >= 0)
        q.min_frame_gap = static_cast<uint64_t>(mSettings.minFrameGap);
    const std::string &l = mSettings.layers;
    if(l == "scal" || l == "SCAL")
        q.layers = humem::Layers::kScal;
    else if(l == "scal_osrl" || l == "SCAL_OSRL")
        q.layers = humem::Layers::kScalOsrl;
    else if(l == "scal_ogtl" || l == "SCAL_OGTL")
        q.layers = humem::Layers::kScalOgtl;
    else if(l == "full" || l == "FULL")
        q.layers = humem::Layers::kFull;
}

// ---------------------------------------------------------------------------
// Tracking hooks

void VprKeyFrameDatabase::NewFrame(const cv::Mat &im, const Frame &F)
{
    // The frame as the camera gave it (the patch passes Tracking's input
    // image, before its grey conversion): the descriptor and OCR models are
    // trained on colour, and on town-dev/loop GRAY8 costs R@1 0.995 -> 0.990
    // and raises first-visit false alarms 4.5 % -> 7.3 % (humem eval --grey).
    // ORB-SLAM3's Camera.RGB is not used: its own examples read BGR with
    // cv::imread and declare Camera.RGB: 1, so HuMem.ImageOrder says it.
    if(im.empty())
        return;
    cv::Mat frame = im;
    if(frame.depth() != CV_8U)
    {
        cv::Mat tmp;
        frame.convertTo(tmp, CV_8U);
        frame = tmp;
    }
    // A grey camera's frame goes as it is; a colour one in colour, or in
    // grey (taken as BGR, OpenCV's order) with HuMem.ImageOrder: gray.
    const bool rgb = mSettings.imageOrder == "rgb";
    const bool four = frame.channels() == 4;
    cv::Mat packed = frame;
    humem::Image::Encoding encoding = humem::Image::kGray8;
    if(frame.channels() != 1 && mSettings.imageOrder == "gray")
        cv::cvtColor(frame, packed, four ? cv::COLOR_BGRA2GRAY : cv::COLOR_BGR2GRAY);
    else if(frame.channels() != 1)
    {
        if(four)
            cv::cvtColor(frame, packed, rgb ? cv::COLOR_RGBA2RGB : cv::COLOR_BGRA2BGR);
        encoding = rgb ? humem::Image::kRgb8 : humem::Image::kBgr8;
    }
    std::shared_ptr<const humem::Image> image = std::make_shared<humem::Image>(
        humem::Image::Raw(encoding, packed.data, static_cast<uint32_t>(packed.cols),
                          static_cast<uint32_t>(packed.rows), packed.step));
    mImages.Put(F.mnId, image);
    std::lock_guard<std::mutex> lock(mMutexHm);
    ++mCounters.framesCached;
}

bool VprKeyFrameDatabase::InsertLocked(KeyFrame* pKF, Entry &entry)
{
    entry.triedInsert = true;
    Map* pMap = pKF->GetMap();
    if(!pMap || pKF->isBad())
        return false;
    std::shared_ptr<const humem::Image> img;
    if(!mImages.Get(pKF->mnFrameId, &img))
    {
        ++mCounters.insertsNoImage;
        std::ostringstream m;
        m << "no cached image of frame " << pKF->mnFrameId << " for KF " << pKF->mnId
          << ": not sent (raise HuMem.ImageCacheFrames)";
        Log(0, m.str());
        return false;
    }
    humem::Keyframe k;
    k.keyframe_id = pKF->mnId;
    k.frame_id = pKF->mnFrameId;
    k.map_id = pMap->GetId();
    k.timestamp = pKF->mTimeStamp;
    k.pose = PoseOf(pKF, entry.sentTwc);
    k.image = img;
    humem::WriteResult w = mClient->Insert(k);
    if(w.state == humem::WriteState::kFailed)
    {
        ++mCounters.insertsRefused;
        ++mRefusedInRow;
        if(mRefusedInRow == 1 || mRefusedInRow % 50 == 0)
            Log(0, "insert of KF " + std::to_string(pKF->mnId) + " refused (" + std::to_string(mRefusedInRow) +
                       " in a row; the keyframe will be missing in HuMem): " + w.status.ToString());
        return false;
    }
    mRefusedInRow = 0;
    entry.inserted = true;
    entry.serverMapId = k.map_id;
    mLastInsertedInMap[static_cast<unsigned long>(k.map_id)] = pKF->mnId;
    ++mCounters.inserts;
    if(mSentLog.is_open())
    {
        std::ostringstream line;
        line << "insert " << k.keyframe_id << " " << k.frame_id << " " << k.map_id << " " << std::fixed
             << std::setprecision(6) << k.timestamp << " " << PoseText(k.pose);
        RecordSentLocked(line.str());
    }
    return true;
}

void VprKeyFrameDatabase::NewKeyFrame(KeyFrame* pKF)
{
    if(!pKF)
        return;
    Map* pMap = pKF->GetMap();
    if(!pMap)
        return;
    const unsigned long mapId = pMap->GetId();
    // (The keyframe joins the map in Local Mapping, hence the + 1.)
    const bool askLoop = static_cast<int>(pMap->KeyFramesInMap()) + 1 >= mSettings.minMapKeyFrames;

    std::lock_guard<std::mutex> lock(mMutexHm);
    ++mCounters.keyframesSeen;
    Entry &entry = mEntries[pKF->mnId];
    entry = Entry();
    entry.kf = pKF;
    if(!InsertLocked(pKF, entry))
        return;

    // Temporal context: the previous keyframes made in the same map, newest first.
    std::vector<uint64_t> predecessors;
    for(size_t i = 0; i < mRecentKFs.size() && predecessors.size() < 2; ++i)
        if(mRecentKFs[i].second == mapId && mRecentKFs[i].first != pKF->mnId)
            predecessors.push_back(mRecentKFs[i].first);
    mRecentKFs.push_front(std::make_pair(pKF->mnId, mapId));
    if(mRecentKFs.size() > 8)
        mRecentKFs.pop_back();

    std::ostringstream m;
    m << "insert KF " << pKF->mnId << " (frame " << pKF->mnFrameId << ", map " << mapId << ")";
    // The loop query asks about the stored keyframe by id, once the insert
    // just queued is applied: the server runs its models once per keyframe,
    // not again for the query.
    if(askLoop && pKF->mnId != 0)
    {
        humem::QueryRequest q;
        q.kind = humem::QueryKind::kLoopClosure;
        q.keyframe_id = static_cast<uint64_t>(pKF->mnId);
        q.frame_id = static_cast<uint64_t>(pKF->mnFrameId);
        q.map_id = static_cast<uint64_t>(mapId);
        q.after_queued_writes = true;
        q.predecessor_keyframe_ids = predecessors;
        ApplyQueryOptions(q, false);
        entry.loopTicket = mClient->SubmitQuery(q);
        ++mCounters.loopQueries;
        RecordSentLocked("query " + std::to_string(pKF->mnId) + " " + std::to_string(mapId));
        m << " + loop query (ticket " << entry.loopTicket << ")";
    }
    Log(2, m.str());
}

void VprKeyFrameDatabase::SubmitRelocalisation(const Frame &F, Map* pMap)
{
    std::shared_ptr<const humem::Image> image;
    if(!mImages.Get(F.mnId, &image))
        return;
    humem::QueryRequest q;
    q.kind = humem::QueryKind::kRelocalisation;
    q.frame_id = static_cast<uint64_t>(F.mnId);
    if(pMap)
        q.map_id = static_cast<uint64_t>(pMap->GetId());
    q.image = image;
    ApplyQueryOptions(q, true);
    humem::Ticket t = mClient->SubmitQuery(q);
    std::lock_guard<std::mutex> lock(mMutexHm);
    ++mCounters.relocQueries;
    mRelocTickets[t] = F.mnId;
    while(mRelocTickets.size() > 64)
        mRelocTickets.erase(mRelocTickets.begin());
}

void VprKeyFrameDatabase::TrackingRecentlyLost(Frame* F, Map* pMap)
{
    if(!F)
        return;
    {
        std::lock_guard<std::mutex> lock(mMutexHm);
        mHaveReloc = false;
    }
    Log(1, "tracking lost at frame " + std::to_string(F->mnId) + ": relocalisation query submitted");
    SubmitRelocalisation(*F, pMap);
}

// ---------------------------------------------------------------------------
// Database maintenance

void VprKeyFrameDatabase::add(KeyFrame* pKF)
{
    KeyFrameDatabase::add(pKF);  // the DBoW2 inverted file, as before
    if(!pKF)
        return;
    {
        std::lock_guard<std::mutex> lock(mMutexHm);
        Entry &entry = mEntries[pKF->mnId];
        if(entry.kf != pKF)
        {
            // Not seen by NewKeyFrame (e.g. loaded with an atlas): register it,
            // and send it if its image is still cached.
            entry = Entry();
            entry.kf = pKF;
        }
        if(!entry.inserted && !entry.triedInsert)
            InsertLocked(pKF, entry);
    }
    // LoopClosing gets each keyframe after Local Mapping's BA moved it and
    // its neighbours: keep HuMem's poses in step (debug log unless a
    // keyframe changed maps).
    SyncMap(pKF->GetMap(), "local mapping", 2);
}

void VprKeyFrameDatabase::MapCorrected(Map* pMap)
{
    SyncMap(pMap, "loop closure / merge / global BA", 1);
}

void VprKeyFrameDatabase::SyncMap(Map* pMap, const char* why, int logLevel)
{
    // Which keyframes changed is found by comparing with what HuMem was sent,
    // not by watching ORB-SLAM3's change counters: v1.0's monocular merge
    // (MergeLocal) moves keyframes into the old map and renames it
    // (Map::ChangeId) without raising GetLastBigChangeIdx, and a keyframe
    // made after the merge is already in the renamed map, so nothing
    // flagged the moved keyframes (runs with 3 and 2 merges sent 1 and 0
    // pose updates, and the store kept their old map ids).
    if(!mSettings.poseUpdates || !pMap || pMap->IsBad())
        return;
    const unsigned long mapId = pMap->GetId();
    std::vector<KeyFrame*> vpKFs = pMap->GetAllKeyFrames();
    std::vector<humem::PoseUpdate> updates;
    size_t moved = 0;
    std::lock_guard<std::mutex> lock(mMutexHm);
    for(size_t i = 0; i < vpKFs.size(); ++i)
    {
        KeyFrame* pKFi = vpKFs[i];
        if(!pKFi || pKFi->isBad())
            continue;
        std::unordered_map<unsigned long, Entry>::iterator it = mEntries.find(pKFi->mnId);
        if(it == mEntries.end() || it->second.kf != pKFi || !it->second.inserted)
            continue;
        Entry &e = it->second;
        float Twc[12];
        humem::Pose pose = PoseOf(pKFi, Twc);
        const bool mapChanged = e.serverMapId != mapId;
        if(!mapChanged && !PoseChanged(Twc, e.sentTwc))
            continue;
        humem::PoseUpdate u;
        u.keyframe_id = pKFi->mnId;
        u.pose = pose;
        if(mapChanged)
        {
            u.map_id = static_cast<uint64_t>(mapId);
            e.serverMapId = mapId;
            ++moved;
        }
        std::copy(Twc, Twc + 12, e.sentTwc);
        updates.push_back(u);
    }
    if(updates.empty())
        return;
    mClient->UpdatePoses(updates);
    // One flush for the batch: a global BA sends every keyframe of the map.
    for(size_t i = 0; i < updates.size(); ++i)
        RecordSentLocked("pose " + std::to_string(updates[i].keyframe_id) + " " + std::to_string(mapId) + " " +
                             PoseText(updates[i].pose),
                         i + 1 == updates.size());
    ++mCounters.poseUpdates;
    mCounters.posesSent += updates.size();
    std::ostringstream m;
    m << "pose update: " << updates.size() << " of " << vpKFs.size() << " keyframes of map " << mapId << " ("
      << moved << " moved to it) after " << why;
    Log(moved > 0 ? std::min(1, logLevel) : logLevel, m.str());
}

void VprKeyFrameDatabase::erase(KeyFrame* pKF)
{
    KeyFrameDatabase::erase(pKF);
    if(!pKF)
        return;
    std::lock_guard<std::mutex> lock(mMutexHm);
    std::unordered_map<unsigned long, Entry>::iterator it = mEntries.find(pKF->mnId);
    if(it == mEntries.end() || it->second.kf != pKF)
        return;
    if(it->second.inserted)
    {
        mClient->Erase(std::vector<uint64_t>(1, static_cast<uint64_t>(pKF->mnId)));
        ++mCounters.erases;
        RecordSentLocked("erase " + std::to_string(pKF->mnId));
        Log(2, "erase KF " + std::to_string(pKF->mnId));
    }
    mEntries.erase(it);
    std::unordered_map<unsigned long, Proposal>::iterator p = mLoopProposals.find(pKF->mnId);
    if(p != mLoopProposals.end() && p->second.kf == pKF)
        mLoopProposals.erase(p);
}

void VprKeyFrameDatabase::clearMap(Map* pMap)
{
    KeyFrameDatabase::clearMap(pMap);
    if(!pMap)
        return;
    const unsigned long mapId = pMap->GetId();
    std::lock_guard<std::mutex> lock(mMutexHm);
    std::vector<uint64_t> elsewhere;  // keyframes of this map that HuMem holds under another map id
    size_t n = 0;
    for(std::unordered_map<unsigned long, Entry>::iterator it = mEntries.begin(); it != mEntries.end();)
    {
        if(it->second.kf && it->second.kf->GetMap() == pMap)
        {
            if(it->second.inserted && it->second.serverMapId != mapId)
                elsewhere.push_back(it->first);
            ++n;
            it = mEntries.erase(it);
        }
        else
            ++it;
    }
    for(std::unordered_map<unsigned long, Proposal>::iterator it = mLoopProposals.begin(); it != mLoopProposals.end();)
    {
        if(!mEntries.count(it->first) || !mEntries.count(it->second.queryId))
            it = mLoopProposals.erase(it);
        else
            ++it;
    }
    mRelocProposals.clear();
    mLastInsertedInMap.erase(mapId);
    mClient->ResetMap(mapId);
    RecordSentLocked("reset_map " + std::to_string(mapId));
    if(!elsewhere.empty())
        mClient->Erase(elsewhere);
    for(size_t i = 0; i < elsewhere.size(); ++i)
        RecordSentLocked("erase " + std::to_string(elsewhere[i]), i + 1 == elsewhere.size());
    ++mCounters.mapResets;
    Log(1, "map " + std::to_string(mapId) + " reset: ResetMap sent (" + std::to_string(n) + " keyframes forgotten)");
}

void VprKeyFrameDatabase::clear()
{
    KeyFrameDatabase::clear();
    std::lock_guard<std::mutex> lock(mMutexHm);
    // Full reset: ORB-SLAM3 restarts keyframe and frame ids. Empty this
    // session on the server, then continue in a new one so that answers still
    // on their way (about the old ids) can never be mistaken for new keyframes.
    mClient->ResetSession();
    RecordSentLocked("reset_session");
    ++mSessionResets;
    mSessionId = mSettings.sessionId + "-reset" + std::to_string(mSessionResets);
    mClient->SetSession(mSessionId);
    mEntries.clear();
    mRecentKFs.clear();
    mRelocTickets.clear();
    mLoopProposals.clear();
    mRelocProposals.clear();
    mLastInsertedInMap.clear();
    mHaveReloc = false;
    mImages.Clear();
    ++mCounters.sessionResets;
    Log(1, "full reset: ResetSession sent, new session '" + mSessionId + "'");
}

// ---------------------------------------------------------------------------
// Candidates

void VprKeyFrameDatabase::DetectNBestCandidates(KeyFrame *pKF, std::vector<KeyFrame*> &vpLoopCand,
                                                std::vector<KeyFrame*> &vpMergeCand, int nNumCandidates)
{
    if(!pKF)
        return;
    Map* pMap = pKF->GetMap();
    const humem::Ticket ticket = LoopTicketFor(pKF, pMap);
    if(ticket == 0)
    {
        if(mSettings.dbow2Fallback)
            KeyFrameDatabase::DetectNBestCandidates(pKF, vpLoopCand, vpMergeCand, nNumCandidates);
        return;
    }

    // Wait for the answer without holding mMutexHm.
    const std::chrono::steady_clock::time_point t0 = std::chrono::steady_clock::now();
    humem::QueryResult r = mClient->WaitFor(ticket, std::chrono::milliseconds(mSettings.queryDeadlineMs));
    const double waited = MsSince(t0);
    const uint64_t failedInRow = RecordLoopAnswer(pKF, r);
    if(r.state != humem::QueryState::kAnswered)
    {
        LogLoopNotAnswered(pKF, r, waited, failedInRow);
        if(mSettings.dbow2Fallback)
            KeyFrameDatabase::DetectNBestCandidates(pKF, vpLoopCand, vpMergeCand, nNumCandidates);
        return;
    }
    SortLoopCandidates(pKF, pMap, r, waited, vpLoopCand, vpMergeCand, nNumCandidates);
}

humem::Ticket VprKeyFrameDatabase::LoopTicketFor(KeyFrame* pKF, Map* pMap)
{
    humem::Ticket ticket = 0;
    bool inserted = false;
    {
        std::lock_guard<std::mutex> lock(mMutexHm);
        std::unordered_map<unsigned long, Entry>::iterator it = mEntries.find(pKF->mnId);
        if(it != mEntries.end() && it->second.kf == pKF)
        {
            ticket = it->second.loopTicket;
            inserted = it->second.inserted;
        }
    }
    if(ticket == 0 && inserted && pMap)
    {
        // No query was made with the keyframe (its map was small then): ask
        // now about the stored keyframe, once its insert is applied.
        humem::QueryRequest q;
        q.kind = humem::QueryKind::kLoopClosure;
        q.keyframe_id = static_cast<uint64_t>(pKF->mnId);
        q.frame_id = static_cast<uint64_t>(pKF->mnFrameId);
        q.map_id = static_cast<uint64_t>(pMap->GetId());
        q.after_queued_writes = true;
        ApplyQueryOptions(q, false);
        ticket = mClient->SubmitQuery(q);
        std::lock_guard<std::mutex> lock(mMutexHm);
        ++mCounters.loopQueries;
        RecordSentLocked("query " + std::to_string(pKF->mnId) + " " + std::to_string(pMap->GetId()));
    }
    return ticket;
}

uint64_t VprKeyFrameDatabase::RecordLoopAnswer(KeyFrame* pKF, const humem::QueryResult &r)
{
    std::lock_guard<std::mutex> lock(mMutexHm);
    if(r.state == humem::QueryState::kAnswered)
    {
        ++mCounters.loopAnswered;
        mCounters.loopCandidates += r.candidates.size();
    }
    else
        ++mCounters.loopNotAnswered;
    mFailedQueriesInRow = r.state == humem::QueryState::kFailed ? mFailedQueriesInRow + 1 : 0;
    std::unordered_map<unsigned long, Entry>::iterator it = mEntries.find(pKF->mnId);
    if(it != mEntries.end() && it->second.kf == pKF)
        it->second.loopTicket = 0;
    return mFailedQueriesInRow;
}

void VprKeyFrameDatabase::LogLoopNotAnswered(KeyFrame* pKF, const humem::QueryResult &r, double waited,
                                             uint64_t failedInRow)
{
    std::ostringstream m;
    m << "loop query KF " << pKF->mnId << ": " << humem::QueryStateName(r.state);
    if(!r.status.ok())
        m << " (" << r.status.ToString() << ")";
    m << " after waiting " << std::fixed << std::setprecision(0) << waited << " ms: no candidates"
      << (mSettings.dbow2Fallback ? ", DBoW2 fallback" : "");
    if(failedInRow > 1)
        m << " (" << failedInRow << " failed in a row)";
    const bool warn = failedInRow == 1 || (failedInRow > 0 && failedInRow % 50 == 0);
    Log(warn ? 0 : 2, m.str());
}

void VprKeyFrameDatabase::SortLoopCandidates(KeyFrame* pKF, Map* pMap, const humem::QueryResult &r, double waited,
                                             std::vector<KeyFrame*> &vpLoopCand, std::vector<KeyFrame*> &vpMergeCand,
                                             int nNumCandidates)
{
    std::set<KeyFrame*> spConnected = pKF->GetConnectedKeyFrames();
    std::set<KeyFrame*> spAdded;
    std::vector<Proposal> proposals;  // what goes on to geometric verification, for the verdicts
    const std::string session = mClient->session_id();
    std::ostringstream m;
    m << "loop query KF " << pKF->mnId << " (frame " << pKF->mnFrameId << ", map "
      << (pMap ? static_cast<long>(pMap->GetId()) : -1L) << "): " << r.candidates.size()
      << " candidates of " << r.eligible_keyframes << " eligible, round trip " << std::fixed
      << std::setprecision(0) << r.round_trip_seconds * 1000.0 << " ms, waited " << waited << " ms";
    for(size_t i = 0; i < r.candidates.size(); ++i)
    {
        const humem::Candidate &c = r.candidates[i];
        m << "\n[HuMem]    " << DescribeCandidate(c) << " -> ";
        if(c.robot_id != mClient->robot_id() || c.session_id != session)
        {
            m << "skipped: robot '" << c.robot_id << "' session '" << c.session_id << "'";
            continue;
        }
        KeyFrame* pKFi = 0;
        {
            std::lock_guard<std::mutex> lock(mMutexHm);
            std::unordered_map<unsigned long, Entry>::iterator it = mEntries.find(c.keyframe_id);
            if(it != mEntries.end())
                pKFi = it->second.kf;
        }
        if(!pKFi) { m << "skipped: unknown keyframe"; continue; }
        if(pKFi == pKF) { m << "skipped: itself"; continue; }
        // DBoW2 only holds keyframes LoopClosing has already processed; a
        // newer one (LoopClosing lags behind) is for its own turn.
        if(pKFi->mnId > pKF->mnId) { m << "skipped: newer than KF " << pKF->mnId; continue; }
        if(pKFi->isBad()) { m << "skipped: bad"; continue; }
        Map* pMapi = pKFi->GetMap();
        if(!pMapi || pMapi->IsBad()) { m << "skipped: no map"; continue; }
        if(spConnected.count(pKFi)) { m << "skipped: covisible"; continue; }
        if(spAdded.count(pKFi)) { m << "skipped: duplicate"; continue; }
        if(pMapi == pMap)
        {
            if(static_cast<int>(vpLoopCand.size()) >= nNumCandidates) { m << "skipped: enough loop candidates"; continue; }
            vpLoopCand.push_back(pKFi);
            m << "LOOP candidate";
        }
        else
        {
            if(static_cast<int>(vpMergeCand.size()) >= nNumCandidates) { m << "skipped: enough merge candidates"; continue; }
            vpMergeCand.push_back(pKFi);
            m << "MERGE candidate (KF now in map " << pMapi->GetId() << ")";
        }
        spAdded.insert(pKFi);
        Proposal p;
        p.kf = pKFi;
        p.queryId = pKF->mnId;
        p.score = c.score;
        proposals.push_back(p);
    }
    bool logCounters = false;
    {
        std::lock_guard<std::mutex> lock(mMutexHm);
        for(size_t i = 0; i < proposals.size(); ++i)
            mLoopProposals[proposals[i].kf->mnId] = proposals[i];
        mCounters.loopUsed += vpLoopCand.size();
        mCounters.mergeUsed += vpMergeCand.size();
        logCounters = mCounters.loopAnswered % 25 == 0;
    }
    Log(r.candidates.empty() ? 2 : 1, m.str());
    if(logCounters)
        LogCounters();
}

void VprKeyFrameDatabase::LogCounters()
{
    Counters c = GetCounters();
    std::ostringstream m;
    m << "stats: frames cached " << c.framesCached << ", keyframes " << c.keyframesSeen << ", inserts "
      << c.inserts << " (no image " << c.insertsNoImage << ", refused " << c.insertsRefused << "), erases "
      << c.erases << ", map resets " << c.mapResets << ", session resets " << c.sessionResets
      << ", pose updates " << c.poseUpdates << " (" << c.posesSent << " poses), loop queries " << c.loopQueries << " (answered "
      << c.loopAnswered << ", not answered " << c.loopNotAnswered << ", candidates " << c.loopCandidates
      << ", used: loop " << c.loopUsed << " merge " << c.mergeUsed << "), reloc queries " << c.relocQueries
      << " (answers used " << c.relocAnswersUsed << ", candidates " << c.relocCandidates
      << "), verdicts reported " << c.verdictsReported << " (accepted " << c.verdictsAccepted
      << ", not HuMem's " << c.verdictsNotHuMem << ", skipped " << c.verdictsSkipped << "), extra coincidences asked "
      << c.extraCoincidences << ", write failures " << c.writeFailures;
    Log(1, m.str());
}

std::vector<KeyFrame*> VprKeyFrameDatabase::DetectRelocalizationCandidates(Frame* F, Map* pMap)
{
    std::vector<KeyFrame*> out;
    if(!F)
        return out;
    // Ask about this frame (latest wins: while one query is in flight, only
    // the newest waits), and use the newest answer there is. Never blocks.
    SubmitRelocalisation(*F, pMap);

    humem::QueryResult r;
    bool fresh = false;
    while(mClient->Latest(humem::QueryKind::kRelocalisation, &r))
    {
        std::lock_guard<std::mutex> lock(mMutexHm);
        std::map<humem::Ticket, unsigned long>::iterator it = mRelocTickets.find(r.ticket);
        if(it == mRelocTickets.end())
            continue;  // from before a reset
        mRelocFrameId = it->second;
        mReloc = r;
        mHaveReloc = true;
        fresh = true;
    }

    humem::QueryResult answer;
    unsigned long answerFrame = 0;
    std::vector<Proposal> proposals;  // the candidates returned, for the verdicts
    {
        std::lock_guard<std::mutex> lock(mMutexHm);
        if(mHaveReloc && F->mnId >= mRelocFrameId &&
           F->mnId - mRelocFrameId <= static_cast<unsigned long>(std::max(0, mSettings.relocMaxAgeFrames)))
        {
            answer = mReloc;
            answerFrame = mRelocFrameId;
        }
    }
    if(answer.state == humem::QueryState::kAnswered)
    {
        const std::string session = mClient->session_id();
        std::ostringstream m;
        m << "relocalisation frame " << F->mnId << ": answer for frame " << answerFrame << ", "
          << answer.candidates.size() << " candidates";
        for(size_t i = 0; i < answer.candidates.size(); ++i)
        {
            const humem::Candidate &c = answer.candidates[i];
            if(c.robot_id != mClient->robot_id() || c.session_id != session)
                continue;
            KeyFrame* pKFi = 0;
            {
                std::lock_guard<std::mutex> lock(mMutexHm);
                std::unordered_map<unsigned long, Entry>::iterator it = mEntries.find(c.keyframe_id);
                if(it != mEntries.end())
                    pKFi = it->second.kf;
            }
            m << "\n[HuMem]    " << DescribeCandidate(c) << " -> ";
            if(!pKFi || pKFi->isBad()) { m << "skipped: not live"; continue; }
            if(pKFi->GetMap() != pMap) { m << "skipped: not in the current map"; continue; }
            if(std::find(out.begin(), out.end(), pKFi) != out.end()) { m << "skipped: duplicate"; continue; }
            out.push_back(pKFi);
            Proposal p;
            p.kf = pKFi;
            p.score = c.score;
            proposals.push_back(p);
            m << "candidate";
        }
        if(fresh)
        {
            std::lock_guard<std::mutex> lock(mMutexHm);
            ++mCounters.relocAnswersUsed;
            mCounters.relocCandidates += out.size();
        }
        Log(fresh ? 1 : 2, m.str());
    }
    {
        // Tracking::Relocalization reports its verdicts on these (RelocalisationResult) for this frame;
        // DBoW2's fallback candidates are not HuMem's and get none.
        std::lock_guard<std::mutex> lock(mMutexHm);
        mRelocProposals.clear();
        mRelocProposalFrame = F->mnId;
        for(size_t i = 0; i < proposals.size(); ++i)
            mRelocProposals[proposals[i].kf->mnId] = proposals[i];
    }
    if(out.empty() && mSettings.dbow2Fallback)
        return KeyFrameDatabase::DetectRelocalizationCandidates(F, pMap);
    return out;
}

// ---------------------------------------------------------------------------
// Verdicts: ORB-SLAM3's geometric check of the candidates HuMem proposed

bool VprKeyFrameDatabase::StoredLocked(unsigned long id, KeyFrame* pKF) const
{
    std::unordered_map<unsigned long, Entry>::const_iterator it = mEntries.find(id);
    return it != mEntries.end() && it->second.inserted && (!pKF || it->second.kf == pKF);
}

void VprKeyFrameDatabase::Report(unsigned long queryId, KeyFrame* pCandidate, humem::VerificationKind kind,
                                 bool accepted, float score, int inliers,
                                 const humem::Optional<humem::RelativeTransform> &relative, const char* note)
{
    humem::Verification v;
    v.keyframe_id = static_cast<uint64_t>(queryId);
    v.candidate_keyframe_id = static_cast<uint64_t>(pCandidate->mnId);  // the client's robot and session
    v.kind = kind;
    v.accepted = accepted;
    if(accepted)
        v.relative = relative;
    v.score = score;
    v.inliers = static_cast<uint32_t>(std::max(0, inliers));
    // Queued behind the inserts of both keyframes: never blocks.
    const humem::WriteResult w = mClient->ReportVerification(v);
    const char* kindName = kind == humem::VerificationKind::kLoop ? "loop"
                         : kind == humem::VerificationKind::kMerge ? "merge" : "relocalisation";
    {
        std::lock_guard<std::mutex> lock(mMutexHm);
        if(w.state == humem::WriteState::kFailed)
            ++mCounters.verdictsSkipped;
        else
        {
            ++mCounters.verdictsReported;
            if(accepted)
                ++mCounters.verdictsAccepted;
        }
    }
    std::ostringstream m;
    m << "verdict " << kindName << " " << (accepted ? "ACCEPTED" : "rejected") << ": KF " << queryId << " ~ KF "
      << pCandidate->mnId << " (score " << std::fixed << std::setprecision(3) << score << ", " << inliers
      << " inliers" << (note ? note : "") << ")";
    if(w.state == humem::WriteState::kFailed)
        m << " not reported: " << w.status.ToString();
    // Relocalisation rejections come by the dozen while tracking is lost: debug level.
    Log(w.state == humem::WriteState::kFailed ? 0 : (accepted || kind != humem::VerificationKind::kRelocalisation) ? 1 : 2,
        m.str());
}

void VprKeyFrameDatabase::VerificationResult(KeyFrame* pCurrentKF, KeyFrame* pCandidate, int nKind, bool bAccepted,
                                             const Sophus::Sim3f* pScm, int nInliers)
{
    if(!mSettings.reportVerdicts || !pCurrentKF || !pCandidate)
        return;
    const humem::VerificationKind kind =
        nKind == KeyFrameDatabase::VERIFY_MERGE ? humem::VerificationKind::kMerge : humem::VerificationKind::kLoop;
    Proposal p;
    bool queryIsCurrent = false;
    {
        std::lock_guard<std::mutex> lock(mMutexHm);
        std::unordered_map<unsigned long, Proposal>::iterator it = mLoopProposals.find(pCandidate->mnId);
        if(it == mLoopProposals.end() || it->second.kf != pCandidate)
        {
            ++mCounters.verdictsNotHuMem;  // not proposed by HuMem (DBoW2 fallback) or from before a reset
            return;
        }
        p = it->second;
        // The verdict ends this proposal: a later one starts a new verdict.
        mLoopProposals.erase(it);
        // The query is the keyframe HuMem proposed the candidate for; if it is gone (culled), the
        // keyframe ORB-SLAM3 was processing stands in.
        if(!StoredLocked(p.queryId, 0))
            p.queryId = pCurrentKF->mnId;
        queryIsCurrent = p.queryId == pCurrentKF->mnId;
        if(!StoredLocked(p.queryId, 0) || !StoredLocked(pCandidate->mnId, pCandidate) || p.queryId == pCandidate->mnId)
        {
            ++mCounters.verdictsSkipped;
            return;
        }
    }
    if(!bAccepted)
    {
        // A candidate DetectCommonRegionsFromBoW skipped because it is covisible with the keyframe's
        // neighbours is a near place, not a look-alike: no verdict.
        const std::set<KeyFrame*> spConnected = pCurrentKF->GetConnectedKeyFrames();
        std::vector<KeyFrame*> vpCov = pCandidate->GetBestCovisibilityKeyFrames(10);
        vpCov.push_back(pCandidate);
        for(size_t i = 0; i < vpCov.size(); ++i)
            if(spConnected.count(vpCov[i]))
            {
                std::lock_guard<std::mutex> lock(mMutexHm);
                ++mCounters.verdictsSkipped;
                return;
            }
    }
    humem::Optional<humem::RelativeTransform> relative;
    if(bAccepted && pScm)
    {
        // T_qc: the candidate camera in the query camera's frame. pScm is candidate -> current
        // camera; for a query that is not the current keyframe (a detection confirmed over several
        // keyframes), compose with the query's pose relative to the current one (same map).
        Eigen::Matrix4f S = pScm->matrix();
        if(!queryIsCurrent)
        {
            KeyFrame* pQuery = 0;
            {
                std::lock_guard<std::mutex> lock(mMutexHm);
                std::unordered_map<unsigned long, Entry>::iterator e = mEntries.find(p.queryId);
                if(e != mEntries.end())
                    pQuery = e->second.kf;
            }
            if(pQuery)
                S = (pQuery->GetPose() * pCurrentKF->GetPoseInverse()).matrix() * S;
        }
        const float scale = std::cbrt(S.block<3, 3>(0, 0).determinant());
        if(std::isfinite(scale) && scale > 0.f)
        {
            Eigen::Matrix4f T = Eigen::Matrix4f::Identity();
            T.block<3, 3>(0, 0) = S.block<3, 3>(0, 0) / scale;
            T.block<3, 1>(0, 3) = S.block<3, 1>(0, 3);
            relative = humem::RelativeTransform(humem::Pose::FromMatrixColumnMajor(T.data()), scale);
        }
    }
    Report(p.queryId, pCandidate, kind, bAccepted, p.score, nInliers, relative,
           queryIsCurrent ? "" : ", confirmed over later keyframes");
}

void VprKeyFrameDatabase::RelocalisationResult(Frame* F, KeyFrame* pCandidate, bool bAccepted, int nInliers)
{
    if(!mSettings.reportVerdicts || !F || !pCandidate)
        return;
    Proposal p;
    unsigned long queryId = 0;
    {
        std::lock_guard<std::mutex> lock(mMutexHm);
        std::unordered_map<unsigned long, Proposal>::iterator it = mRelocProposals.find(pCandidate->mnId);
        if(mRelocProposalFrame != F->mnId || it == mRelocProposals.end() || it->second.kf != pCandidate)
        {
            ++mCounters.verdictsNotHuMem;
            return;
        }
        p = it->second;
        mRelocProposals.erase(it);
        // A lost frame is no keyframe, so HuMem holds no query for it: the verdict is reported
        // against the newest keyframe inserted in the map the frame relocalises in.
        Map* pMap = pCandidate->GetMap();
        std::map<unsigned long, unsigned long>::iterator last =
            pMap ? mLastInsertedInMap.find(pMap->GetId()) : mLastInsertedInMap.end();
        if(last != mLastInsertedInMap.end())
            queryId = last->second;
        if(last == mLastInsertedInMap.end() || !StoredLocked(queryId, 0) || !StoredLocked(pCandidate->mnId, pCandidate) ||
           queryId == pCandidate->mnId)
        {
            ++mCounters.verdictsSkipped;
            return;
        }
    }
    std::ostringstream note;
    note << ", frame " << F->mnId << " standing in as KF " << queryId;
    // No relative transform: it would be the frame's, not the stand-in keyframe's.
    Report(queryId, pCandidate, humem::VerificationKind::kRelocalisation, bAccepted, p.score, nInliers,
           humem::Optional<humem::RelativeTransform>(), note.str().c_str());
}

int VprKeyFrameDatabase::ExtraCoincidences(KeyFrame* /*pCurrentKF*/, KeyFrame* pCandidate, int /*nKind*/)
{
    if(mSettings.verifyBelowScore <= 0.f || !pCandidate)
        return 0;
    std::lock_guard<std::mutex> lock(mMutexHm);
    std::unordered_map<unsigned long, Proposal>::iterator it = mLoopProposals.find(pCandidate->mnId);
    if(it == mLoopProposals.end() || it->second.kf != pCandidate || it->second.score >= mSettings.verifyBelowScore)
        return 0;
    ++mCounters.extraCoincidences;
    return 1;
}

} // namespace ORB_SLAM3
