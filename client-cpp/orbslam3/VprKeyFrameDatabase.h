// Job: ORB-SLAM3's keyframe database backed by a HuMem place-recognition
// server (the HuMem ORB-SLAM3 plugin).
//
// VprKeyFrameDatabase replaces ORB-SLAM3's DBoW2 place recognition with
// HuMem's. It needs ORB-SLAM3 v1.0 with orbslam3-v1.0.patch applied (virtual
// KeyFrameDatabase methods, a factory, hooks in Tracking) and is compiled
// into libORB_SLAM3 (orbslam3-humem.cmake), where it registers its factory:
// System then asks it for the database, and it reads the `HuMem.*` keys of the
// settings YAML. Without `HuMem.Address`, or with `HuMem.Enabled: 0`, the
// factory returns a plain KeyFrameDatabase: ORB-SLAM3 runs exactly as before.
//
// What it does, per thread of ORB-SLAM3:
//   Tracking     NewFrame: puts the frame as the camera gave it (colour, or
//                grey from a grey camera) in an image ring cache (keyframes
//                do not keep their image).
//                NewKeyFrame: sends the keyframe (its frame's image,
//                T_wc, map id, ids, timestamp) to HuMem and submits its loop
//                query (with the same image) at once.
//                TrackingRecentlyLost / DetectRelocalizationCandidates:
//                submit relocalisation queries for the current frame and use
//                the newest answer there is; never block.
//   LoopClosing  DetectNBestCandidates: waits (up to HuMem.QueryDeadlineMs)
//                for the answer to the query submitted when the keyframe was
//                made, resolves the ids to live keyframes, drops the query's
//                covisible keyframes and splits loop (same map) and merge
//                (other map) candidates by each keyframe's current map.
//                add (after Local Mapping's BA of the keyframe) and
//                MapCorrected (after a loop correction, a merge or a global
//                BA): send the map id and pose of every keyframe of the map
//                whose map id or pose differs from what HuMem was last sent.
//                VerificationResult (after Sim3 and the coincidence check, a
//                loop correction or a merge) and RelocalisationResult (after
//                each relocalisation attempt): report ORB-SLAM3's verdict on
//                each candidate HuMem proposed with ReportVerification
//                (through the client's write queue: never blocks).
//                ExtraCoincidences: one more coincidence for candidates
//                scored below HuMem.VerifyBelowScore.
//   any          erase (KeyFrame::SetBadFlag) -> Erase; clearMap (active map
//                reset) -> ResetMap; clear (full reset: ids restart) ->
//                ResetSession and a new session id.
// The DBoW2 inverted file is kept as well (add/erase/clear call the base
// class), so HuMem.DBoW2Fallback can use it when HuMem has no answer.
//
// C++11, like ORB-SLAM3 (-std=c++11).
#ifndef ORB_SLAM3_VPR_KEYFRAME_DATABASE_H
#define ORB_SLAM3_VPR_KEYFRAME_DATABASE_H

#include <chrono>
#include <cstdint>
#include <deque>
#include <fstream>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <unordered_map>
#include <vector>

#include <humem/humem.h>

#include "KeyFrameDatabase.h"

namespace ORB_SLAM3
{

// The `HuMem.*` keys of ORB-SLAM3's settings YAML (see humem-settings.yaml).
struct HuMemSettings
{
    bool enabled;                 // HuMem.Enabled (default 1; needs Address)
    std::string address;          // HuMem.Address, "host:port" (empty: disabled)
    std::string tlsCaFile;        // HuMem.TlsCaFile: CA bundle, for an https:// address
    std::string tlsCertFile;      // HuMem.TlsCertFile: client certificate (mutual TLS)
    std::string tlsKeyFile;       // HuMem.TlsKeyFile: its key
    std::string tlsServerName;    // HuMem.TlsServerName: name the certificate must hold
    std::string authToken;        // HuMem.AuthToken (or $HUMEM_TOKEN): bearer token, over TLS only
    std::string robotId;          // HuMem.RobotId (default "orbslam3")
    std::string sessionId;        // HuMem.SessionId (default: generated, unique)
    bool resetSessionOnStart;     // HuMem.ResetSessionOnStart (default 0)
    int queryDeadlineMs;          // HuMem.QueryDeadlineMs: LoopClosing waits this long (500)
    int queryTimeoutMs;           // HuMem.QueryTimeoutMs: one query RPC's deadline (5000)
    int imageCacheFrames;         // HuMem.ImageCacheFrames (64)
    int topN;                     // HuMem.TopN (0: server default, 5)
    int relocTopN;                // HuMem.RelocTopN (10; 0: server default)
    float threshold;              // HuMem.Threshold (<0: server default, 0.36 calibrated)
    float relocThreshold;         // HuMem.RelocThreshold (0: none, like DBoW2; <0: as Threshold)
    int minFrameGap;              // HuMem.MinFrameGap for loop queries (<0: server default, 100)
    int relocMinFrameGap;         // HuMem.RelocMinFrameGap (0: recent keyframes too)
    int relocMaxAgeFrames;        // HuMem.RelocMaxAgeFrames: oldest answer used (30)
    std::string layers;           // HuMem.Layers: scal|scal_osrl|scal_ogtl|full ("" = server)
    int minMapKeyFrames;          // HuMem.MinMapKeyFrames: no loop query below (12, as LoopClosing)
    bool dbow2Fallback;           // HuMem.DBoW2Fallback: DBoW2 when HuMem has no answer (0)
    bool poseUpdates;             // HuMem.PoseUpdates: UpdatePoses after loop/GBA/merge (1)
    bool reportVerdicts;          // HuMem.ReportVerdicts: ReportVerification of ORB-SLAM3's verdicts (1)
    float verifyBelowScore;       // HuMem.VerifyBelowScore: candidates scored below need a 4th coincidence (0: off; default 0.5)
    std::string imageOrder;       // HuMem.ImageOrder: bgr (default; cv::imread, VideoCapture) | rgb | gray (send grey)
    int verbose;                  // HuMem.Verbose: 0 warnings, 1 info (default), 2 debug
    std::string sentLog;          // HuMem.SentLog: file that records every pose, erase and loop query sent ("" = none)

    HuMemSettings();
    // Reads the keys from an ORB-SLAM3 settings file; false if it cannot be opened.
    bool Load(const std::string &strSettingsFile);
};

class VprKeyFrameDatabase : public KeyFrameDatabase
{
public:
    // The factory registered with KeyFrameDatabase::SetFactory: a
    // VprKeyFrameDatabase if the settings enable HuMem, else a plain
    // KeyFrameDatabase.
    static KeyFrameDatabase* Create(const ORBVocabulary &voc, const std::string &strSettingsFile);

    VprKeyFrameDatabase(const ORBVocabulary &voc, const HuMemSettings &settings,
                        std::unique_ptr<humem::VprClient> client);
    ~VprKeyFrameDatabase();

    void add(KeyFrame* pKF) override;
    void erase(KeyFrame* pKF) override;
    void clear() override;
    void clearMap(Map* pMap) override;
    void DetectNBestCandidates(KeyFrame *pKF, std::vector<KeyFrame*> &vpLoopCand,
                               std::vector<KeyFrame*> &vpMergeCand, int nNumCandidates) override;
    std::vector<KeyFrame*> DetectRelocalizationCandidates(Frame* F, Map* pMap) override;

    void NewFrame(const cv::Mat &im, const Frame &F) override;
    void NewKeyFrame(KeyFrame* pKF) override;
    void TrackingRecentlyLost(Frame* F, Map* pMap) override;
    void MapCorrected(Map* pMap) override;
    void VerificationResult(KeyFrame* pCurrentKF, KeyFrame* pCandidate, int nKind, bool bAccepted,
                            const Sophus::Sim3f* pScm, int nInliers) override;
    void RelocalisationResult(Frame* F, KeyFrame* pCandidate, bool bAccepted, int nInliers) override;
    int ExtraCoincidences(KeyFrame* pCurrentKF, KeyFrame* pCandidate, int nKind) override;

    // Counters since start (for logs and tests).
    struct Counters
    {
        uint64_t framesCached, keyframesSeen, inserts, insertsNoImage, insertsRefused, erases,
            mapResets, sessionResets, poseUpdates, posesSent, loopQueries, loopAnswered, loopNotAnswered,
            loopCandidates, loopUsed, mergeUsed, relocQueries, relocAnswersUsed, relocCandidates,
            writeFailures, verdictsReported, verdictsAccepted, verdictsNotHuMem, verdictsSkipped,
            extraCoincidences;
        Counters();
    };
    Counters GetCounters();
    // Logs the counters (at info level).
    void LogCounters();
    // Waits until the writes queued so far are applied (e.g. before exiting).
    humem::Status Flush(std::chrono::milliseconds timeout) { return mClient->Flush(timeout); }

private:
    struct Entry
    {
        KeyFrame* kf;
        bool inserted;          // sent to HuMem (not erased since)
        bool triedInsert;
        uint64_t serverMapId;   // map id HuMem holds for it
        float sentTwc[12];      // the pose HuMem holds for it (T_wc, 3x4 row-major)
        humem::Ticket loopTicket;
        Entry() : kf(0), inserted(false), triedInsert(false), serverMapId(0), loopTicket(0)
        {
            for(int i = 0; i < 12; ++i)
                sentTwc[i] = 0.f;
        }
    };

    // A candidate HuMem proposed: for which keyframe (0 for relocalisation), its score, the proposal's kind.
    struct Proposal
    {
        KeyFrame* kf;
        unsigned long queryId;
        float score;
        Proposal() : kf(0), queryId(0), score(0.f) {}
    };

    // Sends pKF (image from the cache); call with mMutex held. False if not sent.
    bool InsertLocked(KeyFrame* pKF, Entry &entry);
    void ApplyQueryOptions(humem::QueryRequest &q, bool reloc) const;
    void SubmitRelocalisation(const Frame &F, Map* pMap);
    // Sends UpdatePoses for the keyframes of pMap whose map id or pose differs
    // from what HuMem holds; `why` goes into the log line.
    void SyncMap(Map* pMap, const char* why, int logLevel);
    void Log(int level, const std::string &message);
    // Appends one line to the sent log (HuMem.SentLog), if any; mMutexHm held, so lines are in the order sent.
    // Flushed at once unless `flush` is false (ORB-SLAM3 never deletes its database, so nothing flushes at exit).
    void RecordSentLocked(const std::string &line, bool flush = true);
    std::string DescribeCandidate(const humem::Candidate &c) const;
    // Whether keyframe id's insert was queued (HuMem holds it, or will once the queue gets there); mMutexHm held.
    bool StoredLocked(unsigned long id, KeyFrame* pKF) const;
    // Queues ReportVerification for (query, candidate); `relative`: T_qc, when accepted and known.
    void Report(unsigned long queryId, KeyFrame* pCandidate, humem::VerificationKind kind, bool accepted,
                float score, int inliers, const humem::Optional<humem::RelativeTransform> &relative,
                const char* note);

    // The steps of DetectNBestCandidates (none holds mMutexHm while calling the client):
    // pKF's loop ticket from NewKeyFrame, else a query submitted now if pKF is stored (0: none).
    humem::Ticket LoopTicketFor(KeyFrame* pKF, Map* pMap);
    // Counts the loop answer and clears pKF's ticket; returns the failed queries in a row.
    uint64_t RecordLoopAnswer(KeyFrame* pKF, const humem::QueryResult &r);
    // Logs an unanswered loop query (a warning for the 1st failure in a row and every 50th).
    void LogLoopNotAnswered(KeyFrame* pKF, const humem::QueryResult &r, double waited, uint64_t failedInRow);
    // Puts the answer's live, non-covisible candidates in vpLoopCand (pMap) or vpMergeCand, and logs them.
    void SortLoopCandidates(KeyFrame* pKF, Map* pMap, const humem::QueryResult &r, double waited,
                            std::vector<KeyFrame*> &vpLoopCand, std::vector<KeyFrame*> &vpMergeCand,
                            int nNumCandidates);

    const HuMemSettings mSettings;
    std::unique_ptr<humem::VprClient> mClient;
    humem::ImageCache mImages;

    std::mutex mMutexHm;  // everything below
    std::string mSessionId;
    unsigned int mSessionResets;
    std::unordered_map<unsigned long, Entry> mEntries;                 // keyframe id -> entry
    std::deque<std::pair<unsigned long, unsigned long> > mRecentKFs;   // (kf id, map id), newest first
    std::map<humem::Ticket, unsigned long> mRelocTickets;              // ticket -> frame id
    std::unordered_map<unsigned long, Proposal> mLoopProposals;        // candidate kf id -> latest loop/merge proposal
    std::unordered_map<unsigned long, Proposal> mRelocProposals;       // candidate kf id -> this attempt's proposal
    unsigned long mRelocProposalFrame;                                 // the frame mRelocProposals are for
    std::map<unsigned long, unsigned long> mLastInsertedInMap;         // map id -> newest keyframe id inserted
    bool mHaveReloc;
    humem::QueryResult mReloc;
    unsigned long mRelocFrameId;
    Counters mCounters;
    uint64_t mRefusedInRow;      // inserts refused since the last accepted one (warnings are thinned)
    uint64_t mFailedQueriesInRow;
    std::ofstream mSentLog;      // HuMem.SentLog, open when set

    std::mutex mMutexLog;
};

} // namespace ORB_SLAM3

#endif // ORB_SLAM3_VPR_KEYFRAME_DATABASE_H
